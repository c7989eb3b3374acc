/* The filter's inner loops for small maps, compiled.
 *
 * With a few landmarks, EKF-SLAM's arithmetic is tiny (P is 15 x 15 for the classic six
 * landmarks) and the numpy version of ekfviz/filters/ekf.py spends its time in the
 * overhead of a dozen numpy calls per landmark. These two functions do the same algebra
 * as EkfSlam.predict and EkfSlam._update_sequential, in the same order, in plain C
 * loops over the filter's own buffers; ekf.py calls predict at any size and the
 * update below KERNEL_MAX_DIM, and falls back to numpy when this module was not built
 * (no C compiler at install time).
 *
 * Buffers are the filter's: x (capacity,) and P (capacity, capacity), C-contiguous
 * float64, of which the leading n entries (n x n block) are the state.
 *
 * Two more serve the model filter of Victoria Park (ModelEkfSlam): its sequential update
 * on a large map, whose changes of P stay pending (model_update), and its Ackermann
 * vehicle's drive (ackermann_drive); see there.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../_doubles.h"

static const double PI = 3.14159265358979323846;
static const double TWO_PI = 6.28318530717958647692;

/* Wrap to (-pi, pi], as models.wrap_angle: remainder() is exact, as math.remainder. */
static double wrap_angle(double angle)
{
    double wrapped = remainder(angle, TWO_PI);
    return wrapped == -PI ? PI : wrapped;
}

/* The state's buffers, checked: x (capacity,), P (capacity, capacity) with capacity >= n. */
static int get_state(PyObject *x_object, PyObject *P_object, Py_ssize_t n, Py_buffer *x,
                     Py_buffer *P, Py_ssize_t *capacity)
{
    if (get_doubles(x_object, x, n, 1, "x") < 0)
        return -1;
    *capacity = x->len / 8;
    if (n < 3 || get_doubles(P_object, P, *capacity * *capacity, 1, "P") < 0) {
        if (n < 3)
            PyErr_SetString(PyExc_ValueError, "n: expected at least 3");
        PyBuffer_Release(x);
        return -1;
    }
    return 0;
}

/* An observation line's buffers: slots (m,) int64, z (m, 2) and table (m, 9) float64,
 * status (m,) bytes, m being the slots' length; checked, and released on failure. */
typedef struct {
    Py_buffer slots, z, table, status;
    Py_ssize_t m;
} Line;

static int get_line(PyObject *slots_object, PyObject *z_object, PyObject *table_object,
                    PyObject *status_object, Line *line)
{
    if (PyObject_GetBuffer(slots_object, &line->slots, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return -1;
    const Py_ssize_t m = line->m = line->slots.len / 8;
    if (line->slots.itemsize != 8 ||
        (strcmp(line->slots.format, "l") != 0 && strcmp(line->slots.format, "q") != 0)) {
        PyErr_SetString(PyExc_ValueError, "slots: expected contiguous int64");
        goto release_slots;
    }
    if (get_doubles(z_object, &line->z, 2 * m, 1, "z") < 0)
        goto release_slots;
    if (get_doubles(table_object, &line->table, 9 * m, 1, "table") < 0)
        goto release_z;
    if (PyObject_GetBuffer(status_object, &line->status, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) < 0)
        goto release_table;
    if (line->status.len < m) {
        PyErr_SetString(PyExc_ValueError, "status: expected one byte per observation");
        PyBuffer_Release(&line->status);
        goto release_table;
    }
    return 0;
release_table:
    PyBuffer_Release(&line->table);
release_z:
    PyBuffer_Release(&line->z);
release_slots:
    PyBuffer_Release(&line->slots);
    return -1;
}

static void release_line(Line *line)
{
    PyBuffer_Release(&line->status);
    PyBuffer_Release(&line->table);
    PyBuffer_Release(&line->z);
    PyBuffer_Release(&line->slots);
}

PyDoc_STRVAR(predict_doc,
"predict(x, P, n, d, alpha, qx, qy, qa) -> bool\n\n"
"EkfSlam.predict in place: drive d along the heading, then turn alpha. P_rm' = G P_rm\n"
"and P_rr' = G P_rr G^T + W Q W^T with Q = diag(qx, qy, qa). Returns whether the new\n"
"pose block is finite.");

static PyObject *predict(PyObject *self, PyObject *args)
{
    PyObject *x_object, *P_object;
    Py_ssize_t n, capacity;
    double d, alpha, qx, qy, qa;
    Py_buffer xb, Pb;
    if (!PyArg_ParseTuple(args, "OOnddddd", &x_object, &P_object, &n, &d, &alpha, &qx, &qy,
                          &qa))
        return NULL;
    if (get_state(x_object, P_object, n, &xb, &Pb, &capacity) < 0)
        return NULL;
    double *x = xb.buf, *P = Pb.buf;
    double *P0 = P, *P1 = P + capacity, *P2 = P + 2 * capacity;
    double px = x[0], py = x[1], theta = x[2];
    double c = cos(theta), s = sin(theta);
    x[0] = px + d * c;
    x[1] = py + d * s;
    x[2] = wrap_angle(theta + alpha);
    double a = -d * s, b = d * c; /* G[0, 2], G[1, 2] */
    double p00 = P0[0], p01 = P0[1], p02 = P0[2], p11 = P1[1], p12 = P1[2], p22 = P2[2];
    for (Py_ssize_t j = 3; j < n; ++j) { /* rows 0, 1 of G P, and their mirror */
        double r0 = P0[j] + a * P2[j], r1 = P1[j] + b * P2[j];
        P0[j] = r0;
        P1[j] = r1;
        P[j * capacity] = r0;
        P[j * capacity + 1] = r1;
    }
    double r02 = p02 + a * p22, r12 = p12 + b * p22;
    double m00 = p00 + a * p02 + a * r02 + c * c * qx + s * s * qy;
    double m01 = p01 + a * p12 + b * r02 + c * s * (qx - qy);
    double m11 = p11 + b * p12 + b * r12 + s * s * qx + c * c * qy;
    double m22 = p22 + qa;
    P0[0] = m00, P0[1] = m01, P0[2] = r02;
    P1[0] = m01, P1[1] = m11, P1[2] = r12;
    P2[0] = r02, P2[1] = r12, P2[2] = m22;
    int finite = isfinite(m00 + m11 + m22 + px + py + d + alpha);
    PyBuffer_Release(&xb);
    PyBuffer_Release(&Pb);
    return PyBool_FromLong(finite);
}

/* What update_sequential says of each observation (its `status` buffer). */
enum { UPDATED = 0, NOT_KNOWN = 1, ZERO_RANGE = 2, NOT_DEFINITE = 3 };
/* What it says of the whole call. */
enum { OK = 0, S_NOT_FINITE = 1, STATE_NOT_FINITE = 2 };

PyDoc_STRVAR(update_sequential_doc,
"update_sequential(x, P, n, slots, z, table, status, r00, r11, min_range)\n"
"-> (code, k, skipped)\n\n"
"EkfSlam._update_sequential in place: the EKF update with each landmark k whose\n"
"slots[k] (int64, the index of its x in the state) is not negative, in order, at\n"
"z[k] = (bearing, range). Writes table[k] = (z_pred, innovation, S row-major, NIS) and\n"
"status[k] (int8: 0 updated, 1 not a known landmark, 2 skipped at zero range, 3 skipped\n"
"as S is not positive definite; a range skipped at is kept in table[k, 1]); skipped\n"
"counts statuses 2 and 3. code 0: done; 1: S of landmark k is not finite; 2: the state\n"
"became non-finite (at landmark k, or k = -1 once the line was done); the state is\n"
"then left as it was at that point.");

static PyObject *update_sequential(PyObject *self, PyObject *args)
{
    PyObject *x_object, *P_object, *slots_object, *z_object, *table_object, *status_object;
    Py_ssize_t n, capacity;
    double r00, r11, min_range;
    if (!PyArg_ParseTuple(args, "OOnOOOOddd", &x_object, &P_object, &n, &slots_object,
                          &z_object, &table_object, &status_object, &r00, &r11, &min_range))
        return NULL;
    Py_buffer xb, Pb;
    Line line;
    if (get_state(x_object, P_object, n, &xb, &Pb, &capacity) < 0)
        return NULL;
    if (get_line(slots_object, z_object, table_object, status_object, &line) < 0)
        goto release_state;
    const Py_ssize_t m = line.m;
    double *hp = malloc(2 * (size_t)n * sizeof(double));
    if (hp == NULL) {
        PyErr_NoMemory();
        goto release_line;
    }

    double *x = xb.buf, *P = Pb.buf, *z = line.z.buf, *table = line.table.buf;
    const int64_t *slots = line.slots.buf;
    int8_t *status = line.status.buf;
    double *h0 = hp, *h1 = hp + n; /* the two rows of H P, then of A = L^-1 H P */
    int code = OK;
    Py_ssize_t failed = -1, skipped = 0;
    for (Py_ssize_t k = 0; k < m && code == OK; ++k) {
        int64_t j = slots[k];
        if (j < 3 || j + 1 >= n) {
            status[k] = NOT_KNOWN;
            continue;
        }
        double dx = x[j] - x[0], dy = x[j + 1] - x[1];
        double q = dx * dx + dy * dy;
        double rng = sqrt(q);
        if (!(rng > min_range)) {
            table[9 * k + 1] = rng; /* for the warning; the caller sets the row back to NaN */
            status[k] = ZERO_RANGE;
            ++skipped;
            continue;
        }
        double bearing = remainder(atan2(dy, dx) - x[2], TWO_PI);
        if (bearing == -PI)
            bearing = PI;
        /* H's 5 non-zero columns (0, 1, 2, j, j+1): (e, -f, -1, -e, f) over (-g, -h, 0, g, h) */
        double e = dy / q, f = dx / q, g = dx / rng, h = dy / rng;
        const double *R0 = P, *R1 = P + capacity, *R2 = P + 2 * capacity;
        const double *Rj = P + j * capacity, *Rj1 = P + (j + 1) * capacity;
        for (Py_ssize_t col = 0; col < n; ++col) {
            h0[col] = e * R0[col] - f * R1[col] - R2[col] - e * Rj[col] + f * Rj1[col];
            h1[col] = -g * R0[col] - h * R1[col] + g * Rj[col] + h * Rj1[col];
        }
        double s00 = e * (h0[0] - h0[j]) - f * (h0[1] - h0[j + 1]) - h0[2] + r00;
        double s01 = g * (h0[j] - h0[0]) + h * (h0[j + 1] - h0[1]);
        double s11 = g * (h1[j] - h1[0]) + h * (h1[j + 1] - h1[1]) + r11;
        double nu0 = remainder(z[2 * k] - bearing, TWO_PI), nu1 = z[2 * k + 1] - rng;
        double *row = table + 9 * k;
        row[0] = bearing, row[1] = rng, row[2] = nu0, row[3] = nu1;
        row[4] = s00, row[5] = s01, row[6] = s01, row[7] = s11, row[8] = NAN;
        /* Cholesky of the 2x2 S; "!(>)" also catches NaN */
        double l00 = s00 > 0.0 ? sqrt(s00) : 0.0;
        double l10 = l00 > 0.0 ? s01 / l00 : 0.0;
        double d11 = s11 - l10 * l10;
        if (!(l00 > 0.0 && d11 > 0.0)) {
            if (!isfinite(s00 + s01 + s11))
                code = S_NOT_FINITE, failed = k;
            status[k] = NOT_DEFINITE;
            ++skipped;
            continue;
        }
        double l11 = sqrt(d11);
        double w0 = nu0 / l00, w1 = (nu1 - l10 * w0) / l11;
        if (!isfinite(w0 + w1)) {
            code = STATE_NOT_FINITE, failed = k;
            break;
        }
        double i00 = 1.0 / l00, i11 = 1.0 / l11, i10 = -l10 * i00 * i11;
        double c0 = w0 * i00 + w1 * i10, c1 = w1 * i11; /* (S^-1 nu)^T H P = c0 h0 + c1 h1 */
        for (Py_ssize_t col = 0; col < n; ++col) {
            double a = h0[col], b = h1[col];
            x[col] += c0 * a + c1 * b;
            h0[col] = i00 * a;
            h1[col] = i10 * a + i11 * b;
        }
        /* P -= A^T A: a_r a_c + b_r b_c is the same float as a_c a_r + b_c b_r, so P stays
         * exactly symmetric */
        for (Py_ssize_t r = 0; r < n; ++r) {
            double a = h0[r], b = h1[r];
            double *P_r = P + r * capacity;
            for (Py_ssize_t col = 0; col < n; ++col)
                P_r[col] -= a * h0[col] + b * h1[col];
        }
        row[8] = w0 * w0 + w1 * w1;
        status[k] = UPDATED;
    }
    if (code == OK) {
        x[2] = wrap_angle(x[2]); /* once per line: the bearings above are wrapped */
        double sum = 0.0;
        for (Py_ssize_t i = 0; i < n; ++i)
            sum += x[i];
        if (!isfinite(sum))
            code = STATE_NOT_FINITE;
    }
    free(hp);
    release_line(&line);
    PyBuffer_Release(&Pb);
    PyBuffer_Release(&xb);
    return Py_BuildValue("(inn)", code, failed, skipped);

release_line:
    release_line(&line);
release_state:
    PyBuffer_Release(&Pb);
    PyBuffer_Release(&xb);
    return NULL;
}

/* ---- the model filter's sequential update on a large map (ModelEkfSlam) ------------
 *
 * ModelEkfSlam._update_sequential's loop over a scan's landmarks, its rank-2 changes of
 * P kept pending in U (P_current = P - U^T U, see ekf.py). Its cost is a few passes over
 * n doubles per landmark: H P's rows (5 of P, rank of U) combined, then the whitened
 * rows. Those loops run 4 doubles at a time with fused multiply-adds where the CPU has
 * AVX2 and FMA (as numpy's BLAS does), else plainly: the sums are numpy's to round-off,
 * not to the bit (the model filter replays Victoria Park alone).
 */

/* out0 = sum_t c0[t] rows[t], out1 = sum_t c1[t] rows[t] over n columns */
static void combine_plain(double *out0, double *out1, const double *const *rows,
                          const double *c0, const double *c1, Py_ssize_t count, Py_ssize_t n)
{
    for (Py_ssize_t j = 0; j < n; ++j)
        out0[j] = out1[j] = 0.0;
    for (Py_ssize_t t = 0; t < count; ++t) {
        const double *row = rows[t], a = c0[t], b = c1[t];
        for (Py_ssize_t j = 0; j < n; ++j) {
            out0[j] += a * row[j];
            out1[j] += b * row[j];
        }
    }
}

/* u0 = i00 h0, u1 = i10 h0 + i11 h1, x += g0 h0 + g1 h1 over n columns */
static void whiten_plain(double *u0, double *u1, double *x, const double *h0, const double *h1,
                         double i00, double i10, double i11, double g0, double g1, Py_ssize_t n)
{
    for (Py_ssize_t j = 0; j < n; ++j) {
        u0[j] = i00 * h0[j];
        u1[j] = i10 * h0[j] + i11 * h1[j];
        x[j] += g0 * h0[j] + g1 * h1[j];
    }
}

#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#define HAVE_WIDE 1

__attribute__((target("avx2,fma"))) static void
combine_wide(double *out0, double *out1, const double *const *rows, const double *c0,
             const double *c1, Py_ssize_t count, Py_ssize_t n)
{
    const Py_ssize_t wide = n - n % 4;
    for (Py_ssize_t j = 0; j < n; ++j)
        out0[j] = out1[j] = 0.0;
    Py_ssize_t t = 0;
    for (; t + 4 <= count; t += 4) { /* four rows per pass over the outputs */
        const double *r0 = rows[t], *r1 = rows[t + 1], *r2 = rows[t + 2], *r3 = rows[t + 3];
        const __m256d a0 = _mm256_set1_pd(c0[t]), a1 = _mm256_set1_pd(c0[t + 1]);
        const __m256d a2 = _mm256_set1_pd(c0[t + 2]), a3 = _mm256_set1_pd(c0[t + 3]);
        const __m256d b0 = _mm256_set1_pd(c1[t]), b1 = _mm256_set1_pd(c1[t + 1]);
        const __m256d b2 = _mm256_set1_pd(c1[t + 2]), b3 = _mm256_set1_pd(c1[t + 3]);
        for (Py_ssize_t j = 0; j < wide; j += 4) {
            const __m256d v0 = _mm256_loadu_pd(r0 + j), v1 = _mm256_loadu_pd(r1 + j);
            const __m256d v2 = _mm256_loadu_pd(r2 + j), v3 = _mm256_loadu_pd(r3 + j);
            __m256d o0 = _mm256_loadu_pd(out0 + j), o1 = _mm256_loadu_pd(out1 + j);
            o0 = _mm256_fmadd_pd(a0, v0, o0);
            o1 = _mm256_fmadd_pd(b0, v0, o1);
            o0 = _mm256_fmadd_pd(a1, v1, o0);
            o1 = _mm256_fmadd_pd(b1, v1, o1);
            o0 = _mm256_fmadd_pd(a2, v2, o0);
            o1 = _mm256_fmadd_pd(b2, v2, o1);
            o0 = _mm256_fmadd_pd(a3, v3, o0);
            o1 = _mm256_fmadd_pd(b3, v3, o1);
            _mm256_storeu_pd(out0 + j, o0);
            _mm256_storeu_pd(out1 + j, o1);
        }
        for (Py_ssize_t j = wide; j < n; ++j) {
            out0[j] += c0[t] * r0[j] + c0[t + 1] * r1[j] + c0[t + 2] * r2[j] + c0[t + 3] * r3[j];
            out1[j] += c1[t] * r0[j] + c1[t + 1] * r1[j] + c1[t + 2] * r2[j] + c1[t + 3] * r3[j];
        }
    }
    for (; t < count; ++t) {
        const double *row = rows[t];
        const __m256d a = _mm256_set1_pd(c0[t]), b = _mm256_set1_pd(c1[t]);
        for (Py_ssize_t j = 0; j < wide; j += 4) {
            const __m256d v = _mm256_loadu_pd(row + j);
            _mm256_storeu_pd(out0 + j, _mm256_fmadd_pd(a, v, _mm256_loadu_pd(out0 + j)));
            _mm256_storeu_pd(out1 + j, _mm256_fmadd_pd(b, v, _mm256_loadu_pd(out1 + j)));
        }
        for (Py_ssize_t j = wide; j < n; ++j) {
            out0[j] += c0[t] * row[j];
            out1[j] += c1[t] * row[j];
        }
    }
}

__attribute__((target("avx2,fma"))) static void
whiten_wide(double *u0, double *u1, double *x, const double *h0, const double *h1, double i00,
            double i10, double i11, double g0, double g1, Py_ssize_t n)
{
    const Py_ssize_t wide = n - n % 4;
    const __m256d I00 = _mm256_set1_pd(i00), I10 = _mm256_set1_pd(i10);
    const __m256d I11 = _mm256_set1_pd(i11), G0 = _mm256_set1_pd(g0), G1 = _mm256_set1_pd(g1);
    for (Py_ssize_t j = 0; j < wide; j += 4) {
        const __m256d v0 = _mm256_loadu_pd(h0 + j), v1 = _mm256_loadu_pd(h1 + j);
        _mm256_storeu_pd(u0 + j, _mm256_mul_pd(I00, v0));
        _mm256_storeu_pd(u1 + j, _mm256_fmadd_pd(I11, v1, _mm256_mul_pd(I10, v0)));
        const __m256d change = _mm256_fmadd_pd(G1, v1, _mm256_mul_pd(G0, v0));
        _mm256_storeu_pd(x + j, _mm256_add_pd(_mm256_loadu_pd(x + j), change));
    }
    whiten_plain(u0 + wide, u1 + wide, x + wide, h0 + wide, h1 + wide, i00, i10, i11, g0, g1,
                 n - wide);
}

static int wide_ok(void)
{
    static int known = -1;
    if (known < 0) {
        __builtin_cpu_init();
        known = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    }
    return known;
}
#else
#define HAVE_WIDE 0
#endif

static void combine(double *out0, double *out1, const double *const *rows, const double *c0,
                    const double *c1, Py_ssize_t count, Py_ssize_t n, int allow_wide)
{
#if HAVE_WIDE
    if (allow_wide && wide_ok()) {
        combine_wide(out0, out1, rows, c0, c1, count, n);
        return;
    }
#endif
    combine_plain(out0, out1, rows, c0, c1, count, n);
}

static void whiten(double *u0, double *u1, double *x, const double *h0, const double *h1,
                   double i00, double i10, double i11, double g0, double g1, Py_ssize_t n,
                   int allow_wide)
{
#if HAVE_WIDE
    if (allow_wide && wide_ok()) {
        whiten_wide(u0, u1, x, h0, h1, i00, i10, i11, g0, g1, n);
        return;
    }
#endif
    whiten_plain(u0, u1, x, h0, h1, i00, i10, i11, g0, g1, n);
}

PyDoc_STRVAR(model_update_doc,
"model_update(x, P, U, n, rank, slots, z, table, status, start, a, b, r00, r01, r11,\n"
"min_range, wide=True) -> (code, k, rank)\n\n"
"ModelEkfSlam._update_sequential in place, from landmark `start` of the line on: the\n"
"update with each landmark k whose slots[k] (int64) is not negative, in order, at z[k],\n"
"with the sensor `a` ahead and `b` left of the pose, its rank-2 change of P appended to\n"
"U (rows x capacity, the current P being P - U[:rank]^T U[:rank]). Writes table[k] and\n"
"status[k] as update_sequential does. code 0: done (k = len(slots)); 1: S of landmark k\n"
"is not finite; 3: U is full, after landmark k - 1 (fold it into P at once, then go on\n"
"from k if k < len(slots)).\n"
"rank: U's rows in use at that point. wide=False: the plain loops, whatever the CPU.");

static PyObject *model_update(PyObject *self, PyObject *args)
{
    PyObject *x_object, *P_object, *U_object, *slots_object, *z_object, *table_object,
        *status_object;
    Py_ssize_t n, rank, start, capacity;
    double a, b, r00, r01, r11, min_range;
    int allow_wide = 1;
    if (!PyArg_ParseTuple(args, "OOOnnOOOOndddddd|p", &x_object, &P_object, &U_object, &n,
                          &rank, &slots_object, &z_object, &table_object, &status_object,
                          &start, &a, &b, &r00, &r01, &r11, &min_range, &allow_wide))
        return NULL;
    Py_buffer xb, Pb, Ub;
    Line line;
    PyObject *result = NULL;
    if (get_state(x_object, P_object, n, &xb, &Pb, &capacity) < 0)
        return NULL;
    if (get_doubles(U_object, &Ub, 2 * capacity, 1, "U") < 0)
        goto release_state;
    const Py_ssize_t U_rows = Ub.len / 8 / capacity;
    if (rank < 0 || rank + 2 > U_rows || rank % 2 || start < 0) {
        PyErr_SetString(PyExc_ValueError, "rank: expected even, below U's rows; start >= 0");
        goto release_U;
    }
    if (get_line(slots_object, z_object, table_object, status_object, &line) < 0)
        goto release_U;
    const Py_ssize_t m = line.m;
    const int64_t *slots = line.slots.buf;
    for (Py_ssize_t k = 0; k < m; ++k) {
        if (slots[k] >= 0 && (slots[k] < 3 || slots[k] + 2 > n)) {
            PyErr_SetString(PyExc_ValueError, "slots: expected landmark rows of the state");
            goto release_line;
        }
    }
    double *x = xb.buf, *P = Pb.buf, *U = Ub.buf, *table = line.table.buf;
    const double *z = line.z.buf;
    int8_t *status = line.status.buf;
    double *HP = malloc((size_t)(2 * n + 6 * (U_rows + 5)) * sizeof(double));
    if (HP == NULL) {
        PyErr_NoMemory();
        goto release_line;
    }
    double *HP1 = HP + n, *c0 = HP1 + n, *c1 = c0 + U_rows + 5;
    const double **from = (const double **)(c1 + U_rows + 5);
    int code = 0;
    Py_ssize_t k = start;
    for (; k < m; ++k) {
        double *row = table + 9 * k;
        if (slots[k] < 0) {
            status[k] = 1;
            continue;
        }
        if (rank + 2 > U_rows) {
            code = 3;
            break;
        }
        const Py_ssize_t j = slots[k];
        const Py_ssize_t c[5] = {0, 1, 2, j, j + 1};
        const double theta = x[2], cs = cos(theta), sn = sin(theta);
        const double ox = a * cs - b * sn, oy = a * sn + b * cs;
        const double dx = x[j] - (x[0] + ox), dy = x[j + 1] - (x[1] + oy);
        const double bearing = wrap_angle(atan2(dy, dx) - theta), rng = hypot(dx, dy);
        if (!(rng > min_range)) {
            row[1] = rng;
            status[k] = 2;
            continue;
        }
        const double q = dx * dx + dy * dy, r = sqrt(q);
        const double H0[5] = {dy / q, -dx / q, (dy * -oy - dx * ox) / q - 1.0, -dy / q, dx / q};
        const double H1[5] = {-dx / r, -dy / r, (-dx * -oy - dy * ox) / r, dx / r, dy / r};
        /* H P_current = H P[c] - (H U[:, c]^T) U: the rows of P and of U combined */
        for (int i = 0; i < 5; ++i) {
            from[i] = P + c[i] * capacity;
            c0[i] = H0[i];
            c1[i] = H1[i];
        }
        for (Py_ssize_t t = 0; t < rank; ++t) {
            const double *u = U + t * capacity;
            double s0 = 0.0, s1 = 0.0;
            for (int i = 0; i < 5; ++i) {
                s0 += H0[i] * u[c[i]];
                s1 += H1[i] * u[c[i]];
            }
            from[5 + t] = u;
            c0[5 + t] = -s0;
            c1[5 + t] = -s1;
        }
        combine(HP, HP1, from, c0, c1, 5 + rank, n, allow_wide);
        double S00 = 0.0, S01 = 0.0, S10 = 0.0, S11 = 0.0;
        for (int i = 0; i < 5; ++i) {
            S00 += HP[c[i]] * H0[i];
            S01 += HP[c[i]] * H1[i];
            S10 += HP1[c[i]] * H0[i];
            S11 += HP1[c[i]] * H1[i];
        }
        const double s00 = S00 + r00, s11 = S11 + r11, s01 = 0.5 * (S01 + S10) + r01;
        if (!isfinite(s00 + s01 + s11)) {
            code = 1;
            break;
        }
        const double nu0 = wrap_angle(z[2 * k] - bearing), nu1 = z[2 * k + 1] - rng;
        row[0] = bearing, row[1] = rng, row[2] = nu0, row[3] = nu1;
        row[4] = s00, row[5] = s01, row[6] = s01, row[7] = s11;
        /* the whitened update through the 2x2 Cholesky factor of S (ekf.py's _whitened) */
        const double l00 = s00 > 0.0 ? sqrt(s00) : 0.0;
        const double l10 = l00 > 0.0 ? s01 / l00 : 0.0, d11 = s11 - l10 * l10;
        if (!(l00 > 0.0 && d11 > 0.0)) {
            row[8] = NAN;
            status[k] = 3;
            continue;
        }
        const double l11 = sqrt(d11), w0 = nu0 / l00, w1 = (nu1 - l10 * w0) / l11;
        const double i00 = 1.0 / l00, i11 = 1.0 / l11, i10 = -l10 * i00 * i11;
        whiten(U + rank * capacity, U + (rank + 1) * capacity, x, HP, HP1, i00, i10, i11,
               w0 * i00 + w1 * i10, w1 * i11, n, allow_wide);
        x[2] = wrap_angle(x[2]);
        rank += 2;
        row[8] = w0 * w0 + w1 * w1;
        status[k] = 0;
        if (rank == U_rows) { /* full: folded into P before the next landmark */
            ++k;
            code = 3;
            break;
        }
    }
    free(HP);
    result = Py_BuildValue("(inn)", code, k, rank);
release_line:
    release_line(&line);
release_U:
    PyBuffer_Release(&Ub);
release_state:
    PyBuffer_Release(&xb);
    PyBuffer_Release(&Pb);
    return result;
}

/* ---- the Ackermann vehicle's drive (ModelEkfSlam.drive with models/ackermann.py) ---- */

PyDoc_STRVAR(ackermann_drive_doc,
"ackermann_drive(segments, x, y, theta, p00, p01, p02, p11, p12, p22, L, H, qv, qs)\n"
"-> (x, y, theta, p00, p01, p02, p11, p12, p22, a, b)\n\n"
"ModelEkfSlam.drive's loop over the (speed, steering, dt) spans of `segments` (float64,\n"
"k x 3) with Ackermann.step, in doubles, operation for operation the Python floats'\n"
"(the same results, bit for bit): the pose and its covariance's upper triangle after\n"
"the spans, and G_all's entries (0, 2) and (1, 2), the sums of the spans' G[0, 2] and\n"
"G[1, 2]. L: wheelbase, H: encoder offset, qv and qs: the controls' variances.");

static PyObject *ackermann_drive(PyObject *self, PyObject *args)
{
    PyObject *segments_object;
    double px, py, pt, p00, p01, p02, p11, p12, p22, L, H, qv, qs;
    if (!PyArg_ParseTuple(args, "Oddddddddddddd", &segments_object, &px, &py, &pt, &p00, &p01,
                          &p02, &p11, &p12, &p22, &L, &H, &qv, &qs))
        return NULL;
    Py_buffer sb;
    if (PyObject_GetBuffer(segments_object, &sb, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return NULL;
    if (sb.itemsize != 8 || sb.format == NULL || strcmp(sb.format, "d") != 0 ||
        sb.len % 24 != 0) {
        PyErr_SetString(PyExc_ValueError, "segments: expected k x 3 contiguous float64");
        PyBuffer_Release(&sb);
        return NULL;
    }
    const double *segment = sb.buf;
    const Py_ssize_t count = sb.len / 24;
    double a_all = 0.0, b_all = 0.0;
    for (Py_ssize_t i = 0; i < count; ++i, segment += 3) {
        const double speed = segment[0], steering = segment[1], dt = segment[2];
        if (dt <= 0.0)
            continue;
        /* Ackermann.step */
        const double c = cos(pt), s = sin(pt), t = tan(steering);
        const double sec2 = 1.0 + t * t, k = 1.0 - t * H / L;
        const double v_c = speed / k, vc_D_speed = 1.0 / k;
        const double vc_D_steering = speed * (H / L) * sec2 / (k * k);
        const double nx = px + dt * v_c * c, ny = py + dt * v_c * s;
        const double nt = wrap_angle(pt + dt * v_c * t / L);
        const double g02 = -dt * v_c * s, g12 = dt * v_c * c;
        const double w00 = dt * c * vc_D_speed, w01 = dt * c * vc_D_steering;
        const double w10 = dt * s * vc_D_speed, w11 = dt * s * vc_D_steering;
        const double w20 = dt * t / L * vc_D_speed;
        const double w21 = dt / L * (vc_D_steering * t + v_c * sec2);
        /* G P G^T, G the identity but for G[0, 2] and G[1, 2], then + W Q W^T */
        const double r02 = p02 + g02 * p22, r12 = p12 + g12 * p22;
        const double m00 = (p00 + g02 * p02) + g02 * r02;
        const double m01 = (p01 + g02 * p12) + g12 * r02;
        const double m11 = (p11 + g12 * p12) + g12 * r12;
        p00 = m00 + (qv * w00 * w00 + qs * w01 * w01);
        p01 = m01 + (qv * w00 * w10 + qs * w01 * w11);
        p02 = r02 + (qv * w00 * w20 + qs * w01 * w21);
        p11 = m11 + (qv * w10 * w10 + qs * w11 * w11);
        p12 = r12 + (qv * w10 * w20 + qs * w11 * w21);
        p22 = p22 + (qv * w20 * w20 + qs * w21 * w21);
        a_all += g02;
        b_all += g12;
        px = nx, py = ny, pt = nt;
    }
    PyBuffer_Release(&sb);
    return Py_BuildValue("(ddddddddddd)", px, py, pt, p00, p01, p02, p11, p12, p22, a_all,
                         b_all);
}

static PyMethodDef methods[] = {
    {"predict", predict, METH_VARARGS, predict_doc},
    {"update_sequential", update_sequential, METH_VARARGS, update_sequential_doc},
    {"model_update", model_update, METH_VARARGS, model_update_doc},
    {"ackermann_drive", ackermann_drive, METH_VARARGS, ackermann_drive_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kernel",
    "The filter's inner loops, compiled (see _kernel.c).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__kernel(void)
{
    return PyModule_Create(&module);
}
