/* The association's inner loops, compiled: JCBB's branch and bound (see
 * ekfviz/association/jcbb.py), with its preparation (jcbb), and the gate of a scan
 * (gating.py's gate_scan: gate). The branch and bound comes first.
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

#include "../_doubles.h"

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

/* An int64 buffer of at least `count` items ('q', or 'l' where long is 64 bits). */
static int get_int64s(PyObject *object, Py_buffer *view, Py_ssize_t count, const char *name)
{
    if (PyObject_GetBuffer(object, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return -1;
    if (view->itemsize != 8 || view->format == NULL ||
        (strcmp(view->format, "q") != 0 && strcmp(view->format, "l") != 0) ||
        view->len < count * 8) {
        PyErr_Format(PyExc_ValueError, "%s: expected at least %zd contiguous int64", name, count);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(jcbb_doc,
"jcbb(nu, d2, compatible, C, R, thresholds, m, K, budget, work_budget, max_joint)\n"
"-> None or (pairing, best_d2, nodes, work, exhausted, complete)\n\n"
"jcbb.py's jcbb from its arguments, the preparation of search() included: the\n"
"measurements compatible with some candidate in order, each one's compatible candidates\n"
"nearest first (ties in column order, as a stable sort), each candidate's own block of C\n"
"plus R. nu (m x K x 2), d2 (m x K), C (2K x 2K), R (R00, R01, R11), thresholds (at least\n"
"min(m, max_joint) + 1: the joint gate of p + 1 pairs) float64; compatible (m x K) bool. None where over\n"
"max_joint measurements are in some gate (the caller falls back); pairing (list, m): the\n"
"best pairing's candidate of each measurement, -1.");

static PyObject *jcbb_entry(PyObject *self, PyObject *args)
{
    PyObject *nu_o, *d2_o, *ic_o, *C_o, *R_o, *thr_o;
    Py_ssize_t m, K, max_joint;
    long long budget, work_budget;
    if (!PyArg_ParseTuple(args, "OOOOOOnnLLn", &nu_o, &d2_o, &ic_o, &C_o, &R_o, &thr_o, &m, &K,
                          &budget, &work_budget, &max_joint))
        return NULL;
    if (m < 0 || K < 0) {
        PyErr_SetString(PyExc_ValueError, "m and K: expected sizes");
        return NULL;
    }
    Py_buffer nub, d2b, icb, Cb, Rb, thrb;
    PyObject *result = NULL;
    if (get_doubles(nu_o, &nub, 2 * m * K, 0, "nu") < 0)
        return NULL;
    if (get_doubles(d2_o, &d2b, m * K, 0, "d2") < 0)
        goto release_nu;
    if (PyObject_GetBuffer(ic_o, &icb, PyBUF_C_CONTIGUOUS) < 0)
        goto release_d2;
    if (icb.len < m * K) {
        PyErr_SetString(PyExc_ValueError, "compatible: expected m x K bools");
        goto release_ic;
    }
    if (get_doubles(C_o, &Cb, 4 * K * K, 0, "C") < 0)
        goto release_ic;
    if (get_doubles(R_o, &Rb, 3, 0, "R") < 0)
        goto release_C;
    if (get_doubles(thr_o, &thrb, (m < max_joint ? m : max_joint) + 1, 0, "thresholds") < 0)
        goto release_R;
    const double *nu = nub.buf, *d2 = d2b.buf, *C = Cb.buf, *R = Rb.buf;
    const unsigned char *ic = icb.buf;
    Py_ssize_t depth_total = 0, total = 0;
    for (Py_ssize_t i = 0; i < m; ++i) {
        Py_ssize_t count = 0;
        for (Py_ssize_t k = 0; k < K; ++k)
            count += ic[i * K + k] != 0;
        depth_total += count > 0;
        total += count;
    }
    if (depth_total > max_joint) {
        result = Py_None;
        Py_INCREF(result);
        goto release_thr;
    }
    /* one block for: order, cand_at, cand (int64), own, nu in order (double), and the
     * search's best, chosen, chosen_k (int64) and used (bytes) */
    const size_t slots = (size_t)(depth_total > 0 ? depth_total : 1);
    const size_t words = slots + (slots + 1) + (size_t)(total > 0 ? total : 1) +
                         3 * (size_t)K + 2 * (size_t)K * slots + 3 * slots;
    int64_t *block = malloc(words * 8 + (size_t)(K > 0 ? K : 1));
    if (block == NULL) {
        PyErr_NoMemory();
        goto release_thr;
    }
    int64_t *order = block, *cand_at = order + slots, *cand = cand_at + slots + 1;
    double *own = (double *)(cand + (total > 0 ? total : 1)), *nu_in_order = own + 3 * K;
    int64_t *best = (int64_t *)(nu_in_order + 2 * K * slots);
    int64_t *chosen = best + slots, *chosen_k = chosen + slots;
    unsigned char *used = (unsigned char *)(chosen_k + slots);
    Py_ssize_t depth = 0, at = 0;
    for (Py_ssize_t i = 0; i < m; ++i) {
        const Py_ssize_t start = at;
        for (Py_ssize_t k = 0; k < K; ++k) {
            if (!ic[i * K + k])
                continue;
            /* insertion, nearest first; a tie goes after: the stable order */
            const double value = d2[i * K + k];
            Py_ssize_t c = at++;
            while (c > start && d2[i * K + cand[c - 1]] > value) {
                cand[c] = cand[c - 1];
                --c;
            }
            cand[c] = k;
        }
        if (at == start)
            continue;
        order[depth] = i;
        cand_at[depth] = start;
        memcpy(nu_in_order + 2 * K * depth, nu + 2 * K * i, (size_t)(2 * K) * sizeof(double));
        ++depth;
    }
    cand_at[depth_total] = at;
    for (Py_ssize_t k = 0; k < K; ++k) {
        own[3 * k] = C[(2 * k) * 2 * K + 2 * k] + R[0];
        own[3 * k + 1] = C[(2 * k) * 2 * K + 2 * k + 1] + R[1];
        own[3 * k + 2] = C[(2 * k + 1) * 2 * K + 2 * k + 1] + R[2];
    }
    Search s = {
        .C = C, .K = K, .own = own, .nu = nu_in_order, .cand = cand, .cand_at = cand_at,
        .threshold = thrb.buf, .depth_total = depth_total, .budget = budget,
        .work_budget = work_budget, .best = best, .chosen = chosen, .chosen_k = chosen_k,
        .used = used,
    };
    for (Py_ssize_t d = 0; d < depth_total; ++d)
        best[d] = chosen[d] = -1;
    memset(used, 0, (size_t)(K > 0 ? K : 1));
    Py_BEGIN_ALLOW_THREADS
    search(&s, 0, 0, NULL, NULL, 0.0);
    Py_END_ALLOW_THREADS
    if (s.failed) {
        PyErr_NoMemory();
    } else {
        PyObject *pairing = PyList_New(m);
        if (pairing != NULL) {
            for (Py_ssize_t i = 0; i < m; ++i)
                PyList_SET_ITEM(pairing, i, PyLong_FromLong(-1));
            for (Py_ssize_t d = 0; d < depth_total; ++d) {
                if (best[d] >= 0) {
                    PyObject *old = PyList_GET_ITEM(pairing, order[d]);
                    PyList_SET_ITEM(pairing, order[d], PyLong_FromLongLong(best[d]));
                    Py_DECREF(old);
                }
            }
            result = Py_BuildValue("(NdLLii)", pairing, s.best_d2, (long long)s.nodes,
                                   (long long)s.work, s.exhausted, s.complete);
        }
    }
    free(block);
release_thr:
    PyBuffer_Release(&thrb);
release_R:
    PyBuffer_Release(&Rb);
release_C:
    PyBuffer_Release(&Cb);
release_ic:
    PyBuffer_Release(&icb);
release_d2:
    PyBuffer_Release(&d2b);
release_nu:
    PyBuffer_Release(&nub);
    return result;
}

/* ---- the gate of a scan (see gating.py's gate_scan) ------------------------------ */

#define PI 3.141592653589793 /* np.pi, the double nearest pi */

/* wrap_angles of models/angles.py for one double, operation for operation:
 * np.remainder(a + pi, 2 pi) - pi (numpy's remainder: fmod, moved to the divisor's sign),
 * then -pi made pi. */
static double wrapped(double angle)
{
    const double a = angle + PI, b = 2.0 * PI;
    double mod = fmod(a, b);
    if (mod) {
        if ((b < 0) != (mod < 0))
            mod += b;
    } else {
        mod = copysign(0.0, b);
    }
    const double w = mod - PI;
    return w == -PI ? PI : w;
}

/* One landmark's predicted measurement, innovation covariance and own Jacobian entries,
 * as gating.py's predict_landmarks_of computes them (the same operations in the same
 * order: no product is fused, so every double is numpy's). */
typedef struct {
    double z0, z1, s00, s01, s11, a0, a1, a2, b0, b1, b2;
} Predicted;

typedef struct {
    const double *x, *bearing, *pose_rows, *covs;
    Py_ssize_t n;
    double sx, sy, sx_D, sy_D, theta, r00, r01, r11;
    double p00, p01, p02, p11, p12, p22;
} Map;

static Predicted predicted(const Map *map, Py_ssize_t i)
{
    Predicted p;
    const Py_ssize_t n = map->n;
    const double dx = map->x[3 + 2 * i] - map->sx, dy = map->x[4 + 2 * i] - map->sy;
    const double q = dx * dx + dy * dy, r = sqrt(q);
    p.z0 = wrapped(map->bearing[i] - map->theta);
    p.z1 = r;
    const double a0 = -dy / q, a1 = dx / q, a2 = (dy * map->sx_D - dx * map->sy_D) / q - 1.0;
    const double b0 = dx / r, b1 = dy / r, b2 = (-dx * map->sx_D - dy * map->sy_D) / r;
    const double *row_x = map->pose_rows + 3, *row_y = row_x + n, *row_t = row_y + n;
    const double lx_x = row_x[2 * i], ly_x = row_x[2 * i + 1];
    const double lx_y = row_y[2 * i], ly_y = row_y[2 * i + 1];
    const double lx_t = row_t[2 * i], ly_t = row_t[2 * i + 1];
    const double *cov = map->covs + 4 * i;
    const double c00 = cov[0] - 2.0 * lx_x + map->p00;
    const double c11 = cov[3] - 2.0 * ly_y + map->p11;
    const double c01 = cov[1] - lx_y - ly_x + map->p01;
    const double c02 = lx_t - map->p02, c12 = ly_t - map->p12, p22 = map->p22;
    const double ra0 = a0 * c00 + a1 * c01 + a2 * c02;
    const double ra1 = a0 * c01 + a1 * c11 + a2 * c12;
    const double ra2 = a0 * c02 + a1 * c12 + a2 * p22;
    const double rb0 = b0 * c00 + b1 * c01 + b2 * c02;
    const double rb1 = b0 * c01 + b1 * c11 + b2 * c12;
    const double rb2 = b0 * c02 + b1 * c12 + b2 * p22;
    p.s00 = ra0 * a0 + ra1 * a1 + ra2 * a2 + map->r00;
    p.s01 = 0.5 * ((ra0 * b0 + ra1 * b1 + ra2 * b2) + (rb0 * a0 + rb1 * a1 + rb2 * a2)) +
            map->r01;
    p.s11 = rb0 * b0 + rb1 * b1 + rb2 * b2 + map->r11;
    p.a0 = a0, p.a1 = a1, p.a2 = a2, p.b0 = b0, p.b1 = b1, p.b2 = b2;
    return p;
}

/* mahalanobis2_of of one innovation (u, v) against S: +inf where S is not definite */
static double distance2(const Predicted *p, double u, double v)
{
    const double a = p->s00, b = p->s01, d = p->s11;
    const double det = a * d - b * b;
    if (!(a > 0.0 && det > 0.0))
        return INFINITY;
    return (d * u * u - 2.0 * b * u * v + a * v * v) / det;
}

PyDoc_STRVAR(gate_doc,
"gate(x, bearing, pose_rows, covs, z, values, out, rows, flags) -> g\n\n"
"gating.py's gate_scan over N = (len(x) - 3) // 2 landmarks and m = len(z) // 2\n"
"measurements: x (3 + 2N) the state, bearing (N) np.arctan2(dy, dx) of each landmark\n"
"from the sensor, pose_rows (3 x (3 + 2N)) P's pose rows, covs (N x 2 x 2) the\n"
"landmarks' marginals, z (m x 2), values (sx, sy, dsx/dtheta, dsy/dtheta, theta, R00,\n"
"R01 + R10 halved, R11, gate, new gate), all float64. Writes the g candidates (landmarks\n"
"in some measurement's gate) in order: rows (int64, N) their indices, and into out\n"
"(float64, N (16 + 3m)) their z_pred (g x 2), S (g x 2 x 2), H (g x 2 x 5), d2 (m x g)\n"
"and nu (m x g x 2) one after another; flags (bool, m (N + 1)): the (m x g) individual\n"
"compatibility, then each measurement's 'near' (in some gate at the new gate).");

static PyObject *gate_entry(PyObject *self, PyObject *args)
{
    PyObject *x_o, *bearing_o, *pose_o, *covs_o, *z_o, *values_o, *out_o, *rows_o, *flags_o;
    if (!PyArg_ParseTuple(args, "OOOOOOOOO", &x_o, &bearing_o, &pose_o, &covs_o, &z_o,
                          &values_o, &out_o, &rows_o, &flags_o))
        return NULL;
    Py_buffer xb, bb, pb, cb, zb, vb, ob, rb, fb;
    PyObject *result = NULL;
    if (get_doubles(x_o, &xb, 3, 0, "x") < 0)
        return NULL;
    const Py_ssize_t n = xb.len / 8, N = (n - 3) / 2;
    if (get_doubles(bearing_o, &bb, N, 0, "bearing") < 0)
        goto release_x;
    if (get_doubles(pose_o, &pb, 3 * n, 0, "pose_rows") < 0)
        goto release_b;
    if (get_doubles(covs_o, &cb, 4 * N, 0, "covs") < 0)
        goto release_p;
    if (get_doubles(z_o, &zb, 0, 0, "z") < 0)
        goto release_c;
    const Py_ssize_t m = zb.len / 16;
    if (get_doubles(values_o, &vb, 10, 0, "values") < 0)
        goto release_z;
    if (get_doubles(out_o, &ob, N * (16 + 3 * m), 0, "out") < 0)
        goto release_v;
    if (get_int64s(rows_o, &rb, N, "rows") < 0)
        goto release_o;
    if (PyObject_GetBuffer(flags_o, &fb, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE) < 0)
        goto release_r;
    if (fb.len < m * (N + 1) || ob.readonly || rb.readonly) {
        PyErr_SetString(PyExc_ValueError, "out, rows and flags: expected writable buffers");
        goto release_f;
    }
    const double *v = vb.buf, *z = zb.buf, *pose = pb.buf;
    Map map = {
        .x = xb.buf, .bearing = bb.buf, .pose_rows = pose, .covs = cb.buf, .n = n,
        .sx = v[0], .sy = v[1], .sx_D = v[2], .sy_D = v[3], .theta = v[4],
        .r00 = v[5], .r01 = v[6], .r11 = v[7],
        .p00 = pose[0], .p01 = pose[1], .p02 = pose[2],
        .p11 = pose[n + 1], .p12 = pose[n + 2], .p22 = pose[2 * n + 2],
    };
    const double gate = v[8], new_gate = v[9];
    int64_t *rows = rb.buf;
    unsigned char *flags = fb.buf, *near = flags + m * N;
    memset(near, 0, (size_t)m);
    Py_ssize_t g = 0;
    for (Py_ssize_t i = 0; i < N; ++i) {
        const Predicted p = predicted(&map, i);
        int candidate = 0;
        for (Py_ssize_t j = 0; j < m; ++j) {
            const double d2 = distance2(&p, wrapped(z[2 * j] - p.z0), z[2 * j + 1] - p.z1);
            candidate |= d2 < gate;
            near[j] |= d2 < new_gate;
        }
        if (candidate)
            rows[g++] = i;
    }
    /* the candidates' own values, again from the same doubles (the same results) */
    double *zp = ob.buf, *S = zp + 2 * g, *H = S + 4 * g, *d2 = H + 10 * g, *nu = d2 + m * g;
    for (Py_ssize_t c = 0; c < g; ++c) {
        const Predicted p = predicted(&map, rows[c]);
        zp[2 * c] = p.z0, zp[2 * c + 1] = p.z1;
        S[4 * c] = p.s00, S[4 * c + 1] = S[4 * c + 2] = p.s01, S[4 * c + 3] = p.s11;
        double *h = H + 10 * c;
        h[0] = -p.a0, h[1] = -p.a1, h[2] = p.a2, h[3] = p.a0, h[4] = p.a1;
        h[5] = -p.b0, h[6] = -p.b1, h[7] = p.b2, h[8] = p.b0, h[9] = p.b1;
        for (Py_ssize_t j = 0; j < m; ++j) {
            const double u = wrapped(z[2 * j] - p.z0), w = z[2 * j + 1] - p.z1;
            const double value = distance2(&p, u, w);
            d2[j * g + c] = value;
            nu[2 * (j * g + c)] = u, nu[2 * (j * g + c) + 1] = w;
            flags[j * g + c] = value < gate;
        }
    }
    result = PyLong_FromSsize_t(g);
release_f:
    PyBuffer_Release(&fb);
release_r:
    PyBuffer_Release(&rb);
release_o:
    PyBuffer_Release(&ob);
release_v:
    PyBuffer_Release(&vb);
release_z:
    PyBuffer_Release(&zb);
release_c:
    PyBuffer_Release(&cb);
release_p:
    PyBuffer_Release(&pb);
release_b:
    PyBuffer_Release(&bb);
release_x:
    PyBuffer_Release(&xb);
    return result;
}

static PyMethodDef methods[] = {
    {"gate", gate_entry, METH_VARARGS, gate_doc},
    {"jcbb", jcbb_entry, METH_VARARGS, jcbb_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_search", "JCBB and the scan's gate, compiled (see _search.c).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__search(void)
{
    return PyModule_Create(&module);
}
