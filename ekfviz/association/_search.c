/* JCBB's branch and bound, compiled (see ekfviz/association/jcbb.py).
 *
 * The same search as jcbb.py's `search`, node for node: the same order of candidates,
 * the same bound, the same budget and work counted, the same 2x2 Cholesky of each
 * candidate's Schur complement in doubles. Only the small products (L^-1 times rows of
 * C, the new inverse's block) are summed in plain loops where numpy hands them to BLAS,
 * which may sum in another order: a joint distance can differ in its last bits, which
 * decides nothing short of an exact tie with a gate or another pairing.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    const double *C;          /* (2K x 2K) the candidates' joint covariance, without R */
    Py_ssize_t K;             /* candidates */
    const double *own;        /* (K x 3) each candidate's own block of C plus R */
    const double *nu;         /* (depth_total x K x 2) innovations, measurements in order */
    const int64_t *cand;      /* each depth's candidates, nearest first, one after another */
    const int64_t *cand_at;   /* (depth_total + 1) where each depth's candidates start */
    const double *threshold;  /* (depth_total + 1) the joint gate of a hypothesis of p + 1 pairs */
    Py_ssize_t depth_total;
    int64_t budget, work_budget;
    int64_t nodes, work;
    int exhausted, complete, failed;
    int64_t best_pairs;
    double best_d2;
    int64_t *best;            /* (depth_total) the best pairing: a candidate per depth, -1 */
    int64_t *chosen;          /* (depth_total) the hypothesis: a candidate per depth, -1 */
    int64_t *chosen_k;        /* the candidates chosen, in order (pairs of them) */
    unsigned char *used;      /* (K) */
} Search;

static void search(Search *s, Py_ssize_t depth, Py_ssize_t pairs, const double *L_inv,
                   const double *w, double dist2)
{
    if (s->failed)
        return;
    if (depth == s->depth_total) {
        s->complete = 1;
        if (pairs > s->best_pairs || (pairs == s->best_pairs && pairs && dist2 < s->best_d2)) {
            s->best_pairs = pairs;
            s->best_d2 = dist2;
            memcpy(s->best, s->chosen, (size_t)s->depth_total * sizeof(int64_t));
        }
        return;
    }
    Py_ssize_t reachable = pairs + s->depth_total - depth;
    if (reachable < s->best_pairs ||
        (reachable == s->best_pairs && s->best_pairs && dist2 >= s->best_d2))
        return; /* the bound: no completion of this branch can beat the best */
    const Py_ssize_t K = s->K, size = 2 * pairs, width = 2 * K;
    const double *nu_i = s->nu + 2 * K * depth;
    const int64_t cost = (int64_t)(2 * pairs + 2) * (2 * pairs + 2);
    const double threshold = s->threshold[pairs];
    double *M = NULL, *squares = NULL, *crosses = NULL, *shifts = NULL;
    for (int64_t c = s->cand_at[depth]; c < s->cand_at[depth + 1]; ++c) {
        const int64_t k = s->cand[c];
        if (s->used[k])
            continue;
        if (s->nodes >= s->budget || s->work + cost > s->work_budget) {
            s->exhausted = 1;
            goto done;
        }
        s->nodes += 1;
        s->work += cost;
        double a00 = s->own[3 * k], a01 = s->own[3 * k + 1], a11 = s->own[3 * k + 2];
        double nu0 = nu_i[2 * k], nu1 = nu_i[2 * k + 1];
        if (pairs) {
            if (M == NULL) { /* L^-1 times the rows of the chosen pairs in C, once */
                M = malloc((size_t)(size * width + 2 * width + K) * sizeof(double));
                if (M == NULL) {
                    s->failed = 1;
                    return;
                }
                squares = M + size * width;
                shifts = squares + width;
                crosses = shifts + width;
                for (Py_ssize_t r = 0; r < size; ++r) {
                    double *row = M + r * width;
                    for (Py_ssize_t j = 0; j < width; ++j)
                        row[j] = 0.0;
                    for (Py_ssize_t t = 0; t < size; ++t) {
                        const double l = L_inv[r * size + t];
                        const double *from = s->C + (2 * s->chosen_k[t / 2] + t % 2) * width;
                        for (Py_ssize_t j = 0; j < width; ++j)
                            row[j] += l * from[j];
                    }
                }
                for (Py_ssize_t j = 0; j < width; ++j) {
                    double sq = 0.0, sh = 0.0;
                    for (Py_ssize_t r = 0; r < size; ++r) {
                        sq += M[r * width + j] * M[r * width + j];
                        sh += w[r] * M[r * width + j];
                    }
                    squares[j] = sq;
                    shifts[j] = sh;
                }
                for (Py_ssize_t kk = 0; kk < K; ++kk) {
                    double cr = 0.0;
                    for (Py_ssize_t r = 0; r < size; ++r)
                        cr += M[r * width + 2 * kk] * M[r * width + 2 * kk + 1];
                    crosses[kk] = cr;
                }
            }
            /* S_new - B B^T and nu_new - B w, B = (L^-1 S_cross^T)^T (2 x 2p) */
            a00 -= squares[2 * k];
            a01 -= crosses[k];
            a11 -= squares[2 * k + 1];
            nu0 -= shifts[2 * k];
            nu1 -= shifts[2 * k + 1];
        }
        /* 2x2 Cholesky of the Schur complement */
        if (!(a00 > 0.0))
            continue;
        const double l00 = sqrt(a00), l10 = a01 / l00, d11 = a11 - l10 * l10;
        if (!(d11 > 0.0))
            continue;
        const double l11 = sqrt(d11), w0 = nu0 / l00, w1 = (nu1 - l10 * w0) / l11;
        const double grown = dist2 + w0 * w0 + w1 * w1;
        if (!(grown < threshold))
            continue;
        /* [[L, 0], [B, L22]]^-1 = [[L^-1, 0], [-L22^-1 B L^-1, L22^-1]] */
        const Py_ssize_t n = size + 2;
        double *child = malloc((size_t)(n * n + n) * sizeof(double));
        if (child == NULL) {
            s->failed = 1;
            goto done;
        }
        double *w_new = child + n * n;
        memset(child, 0, (size_t)(n * n) * sizeof(double));
        const double i00 = 1.0 / l00, i10 = -l10 / (l00 * l11), i11 = 1.0 / l11;
        for (Py_ssize_t r = 0; r < size; ++r)
            memcpy(child + r * n, L_inv + r * size, (size_t)size * sizeof(double));
        if (M != NULL) {
            /* T = L22^-1 B (2 x 2p), B[t][r] = M[r][2k + t]; then -T L^-1 */
            for (Py_ssize_t col = 0; col < size; ++col) {
                double t0 = 0.0, t1 = 0.0;
                for (Py_ssize_t r = 0; r < size; ++r) {
                    const double b0 = M[r * width + 2 * k], b1 = M[r * width + 2 * k + 1];
                    const double T0 = i00 * b0, T1 = i10 * b0 + i11 * b1;
                    t0 += T0 * L_inv[r * size + col];
                    t1 += T1 * L_inv[r * size + col];
                }
                child[size * n + col] = -t0;
                child[(size + 1) * n + col] = -t1;
            }
        }
        child[size * n + size] = i00;
        child[(size + 1) * n + size] = i10;
        child[(size + 1) * n + size + 1] = i11;
        if (size)
            memcpy(w_new, w, (size_t)size * sizeof(double));
        w_new[size] = w0;
        w_new[size + 1] = w1;
        s->chosen[depth] = k;
        s->chosen_k[pairs] = k;
        s->used[k] = 1;
        search(s, depth + 1, pairs + 1, child, w_new, grown);
        s->chosen[depth] = -1;
        s->used[k] = 0;
        free(child);
        if (s->exhausted || s->failed)
            goto done;
    }
    if (s->nodes >= s->budget) { /* a hypothesis too: every call counts */
        s->exhausted = 1;
        goto done;
    }
    s->nodes += 1;
    free(M);
    M = NULL;
    search(s, depth + 1, pairs, L_inv, w, dist2); /* this measurement paired with nothing */
done:
    free(M);
}

static int get(PyObject *object, Py_buffer *view, Py_ssize_t count, const char *format,
               const char *name)
{
    if (PyObject_GetBuffer(object, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return -1;
    int ok = view->itemsize == 8 && view->format != NULL &&
             (strcmp(view->format, format) == 0 ||
              (format[0] == 'q' && strcmp(view->format, "l") == 0)) &&
             view->len >= count * 8;
    if (!ok) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd contiguous 8-byte items", name, count);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(search_doc,
"search(C, own, nu, candidates, starts, thresholds, budget, work_budget)\n"
"-> (best, best_pairs, best_d2, nodes, work, exhausted, complete)\n\n"
"jcbb.py's search over depth_total = len(starts) - 1 measurements and K = len(own) // 3\n"
"candidates: C (2K x 2K) float64, own (K x 3) float64 (each candidate's own block plus\n"
"R: S00, S01, S11), nu (depth_total x K x 2) float64, candidates (int64) each depth's\n"
"from starts[depth] to starts[depth + 1], thresholds (depth_total + 1) float64 the gate\n"
"of p + 1 pairs. best (int64, depth_total): the best pairing's candidate per depth, -1.");

static PyObject *search_entry(PyObject *self, PyObject *args)
{
    PyObject *C_o, *own_o, *nu_o, *cand_o, *at_o, *thr_o;
    long long budget, work_budget;
    if (!PyArg_ParseTuple(args, "OOOOOOLL", &C_o, &own_o, &nu_o, &cand_o, &at_o, &thr_o,
                          &budget, &work_budget))
        return NULL;
    Py_buffer Cb, ownb, nub, candb, atb, thrb;
    PyObject *result = NULL;
    if (get(own_o, &ownb, 0, "d", "own") < 0)
        return NULL;
    const Py_ssize_t K = ownb.len / 8 / 3;
    if (get(at_o, &atb, 1, "q", "starts") < 0)
        goto release_own;
    const Py_ssize_t depth_total = atb.len / 8 - 1;
    if (get(C_o, &Cb, 4 * K * K, "d", "C") < 0)
        goto release_at;
    if (get(nu_o, &nub, 2 * K * depth_total, "d", "nu") < 0)
        goto release_C;
    const int64_t *at = atb.buf;
    if (get(cand_o, &candb, at[depth_total], "q", "candidates") < 0)
        goto release_nu;
    if (get(thr_o, &thrb, depth_total + 1, "d", "thresholds") < 0)
        goto release_cand;
    for (Py_ssize_t c = 0; c < at[depth_total]; ++c) {
        int64_t k = ((const int64_t *)candb.buf)[c];
        if (k < 0 || k >= K) {
            PyErr_SetString(PyExc_ValueError, "candidates: expected indices below K");
            goto release_thr;
        }
    }
    Search s = {
        .C = Cb.buf, .K = K, .own = ownb.buf, .nu = nub.buf, .cand = candb.buf,
        .cand_at = at, .threshold = thrb.buf, .depth_total = depth_total,
        .budget = budget, .work_budget = work_budget,
    };
    size_t slots = (size_t)(depth_total > 0 ? depth_total : 1);
    s.best = malloc(3 * slots * sizeof(int64_t) + (size_t)(K > 0 ? K : 1));
    if (s.best == NULL) {
        PyErr_NoMemory();
        goto release_thr;
    }
    s.chosen = s.best + slots;
    s.chosen_k = s.chosen + slots;
    s.used = (unsigned char *)(s.chosen_k + slots);
    for (Py_ssize_t d = 0; d < depth_total; ++d)
        s.best[d] = s.chosen[d] = -1;
    memset(s.used, 0, (size_t)(K > 0 ? K : 1));
    Py_BEGIN_ALLOW_THREADS
    search(&s, 0, 0, NULL, NULL, 0.0);
    Py_END_ALLOW_THREADS
    if (s.failed) {
        PyErr_NoMemory();
    } else {
        PyObject *best = PyList_New(depth_total);
        if (best != NULL) {
            for (Py_ssize_t d = 0; d < depth_total; ++d)
                PyList_SET_ITEM(best, d, PyLong_FromLongLong(s.best[d]));
            result = Py_BuildValue("(NLdLLii)", best, (long long)s.best_pairs, s.best_d2,
                                   (long long)s.nodes, (long long)s.work, s.exhausted,
                                   s.complete);
        }
    }
    free(s.best);
release_thr:
    PyBuffer_Release(&thrb);
release_cand:
    PyBuffer_Release(&candb);
release_nu:
    PyBuffer_Release(&nub);
release_C:
    PyBuffer_Release(&Cb);
release_at:
    PyBuffer_Release(&atb);
release_own:
    PyBuffer_Release(&ownb);
    return result;
}

static PyMethodDef methods[] = {
    {"search", search_entry, METH_VARARGS, search_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_search", "JCBB's branch and bound, compiled (see _search.c).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__search(void)
{
    return PyModule_Create(&module);
}
