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
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

static const double PI = 3.14159265358979323846;
static const double TWO_PI = 6.28318530717958647692;

/* Wrap to (-pi, pi], as models.wrap_angle: remainder() is exact, as math.remainder. */
static double wrap_angle(double angle)
{
    double wrapped = remainder(angle, TWO_PI);
    return wrapped == -PI ? PI : wrapped;
}

/* A writable C-contiguous float64 buffer of at least `count` doubles. */
static int get_doubles(PyObject *object, Py_buffer *view, Py_ssize_t count, const char *name)
{
    if (PyObject_GetBuffer(object, view, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        return -1;
    if (view->itemsize != 8 || view->format == NULL || strcmp(view->format, "d") != 0 ||
        view->len < count * 8) {
        PyErr_Format(PyExc_ValueError, "%s: expected at least %zd contiguous float64", name,
                     count);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* The state's buffers, checked: x (capacity,), P (capacity, capacity) with capacity >= n. */
static int get_state(PyObject *x_object, PyObject *P_object, Py_ssize_t n, Py_buffer *x,
                     Py_buffer *P, Py_ssize_t *capacity)
{
    if (get_doubles(x_object, x, n, "x") < 0)
        return -1;
    *capacity = x->len / 8;
    if (n < 3 || get_doubles(P_object, P, *capacity * *capacity, "P") < 0) {
        if (n < 3)
            PyErr_SetString(PyExc_ValueError, "n: expected at least 3");
        PyBuffer_Release(x);
        return -1;
    }
    return 0;
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
    Py_buffer xb, Pb, slots_b, zb, table_b, status_b;
    if (get_state(x_object, P_object, n, &xb, &Pb, &capacity) < 0)
        return NULL;
    if (PyObject_GetBuffer(slots_object, &slots_b, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
        goto release_state;
    Py_ssize_t m = slots_b.len / 8;
    if (slots_b.itemsize != 8 ||
        (strcmp(slots_b.format, "l") != 0 && strcmp(slots_b.format, "q") != 0)) {
        PyErr_SetString(PyExc_ValueError, "slots: expected contiguous int64");
        goto release_slots;
    }
    if (get_doubles(z_object, &zb, 2 * m, "z") < 0)
        goto release_slots;
    if (get_doubles(table_object, &table_b, 9 * m, "table") < 0)
        goto release_z;
    if (PyObject_GetBuffer(status_object, &status_b, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) < 0)
        goto release_table;
    if (status_b.len < m) {
        PyErr_SetString(PyExc_ValueError, "status: expected one byte per observation");
        goto release_status;
    }
    double *hp = malloc(2 * (size_t)n * sizeof(double));
    if (hp == NULL) {
        PyErr_NoMemory();
        goto release_status;
    }

    double *x = xb.buf, *P = Pb.buf, *z = zb.buf, *table = table_b.buf;
    const int64_t *slots = slots_b.buf;
    int8_t *status = status_b.buf;
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
    PyBuffer_Release(&status_b);
    PyBuffer_Release(&table_b);
    PyBuffer_Release(&zb);
    PyBuffer_Release(&slots_b);
    PyBuffer_Release(&Pb);
    PyBuffer_Release(&xb);
    return Py_BuildValue("(inn)", code, failed, skipped);

release_status:
    PyBuffer_Release(&status_b);
release_table:
    PyBuffer_Release(&table_b);
release_z:
    PyBuffer_Release(&zb);
release_slots:
    PyBuffer_Release(&slots_b);
release_state:
    PyBuffer_Release(&Pb);
    PyBuffer_Release(&xb);
    return NULL;
}

static PyMethodDef methods[] = {
    {"predict", predict, METH_VARARGS, predict_doc},
    {"update_sequential", update_sequential, METH_VARARGS, update_sequential_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kernel",
    "The filter's inner loops for small maps, compiled (see _kernel.c).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__kernel(void)
{
    return PyModule_Create(&module);
}
