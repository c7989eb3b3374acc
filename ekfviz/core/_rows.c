/* A replay's row copies, compiled (see ekfviz.core.records.EventRows).
 *
 * A long log's plain predicts and updates make no record: the replay copies each one's
 * pose and pose covariance, and an update's map (landmark means and 2x2 marginals),
 * from the filter's buffers into column buffers. With numpy that is two to four calls
 * an event and a few arrays made for each update, more than the filter's own step on a
 * small map; here it is one call. The floats are copied as they are: the columns hold
 * what numpy's copies would, to the bit.
 *
 * Buffers: x (capacity,) and P (capacity, capacity), the filter's state in their leading
 * entries; poses (rows, 3), pose_covs (rows, 3, 3), map_xy (room, 2) and map_covs
 * (room, 2, 2), all C-contiguous float64.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>

#include "../_doubles.h"

PyDoc_STRVAR(copy_row_doc,
             "copy_row(x, P, poses, pose_covs, row, map_xy, map_covs, start, count)\n\n"
             "Copy the pose x[:3] into poses[row] and P[:3, :3] into pose_covs[row]; and\n"
             "the first `count` landmarks' means x[3:3+2*count] into map_xy[start:]\n"
             "and their 2x2 diagonal blocks of P into map_covs[start:]. P is square,\n"
             "of x's capacity.");

static PyObject *copy_row(PyObject *self, PyObject *args)
{
    PyObject *x_object, *P_object, *poses_object, *covs_object, *xy_object, *map_covs_object;
    Py_ssize_t row, start, count;
    if (!PyArg_ParseTuple(args, "OOOOnOOnn", &x_object, &P_object, &poses_object,
                          &covs_object, &row, &xy_object, &map_covs_object, &start, &count))
        return NULL;
    if (row < 0 || start < 0 || count < 0) {
        PyErr_SetString(PyExc_ValueError, "row, start and count: expected at least 0");
        return NULL;
    }
    Py_buffer xb, Pb, posesb, covsb, xyb, mapb;
    if (get_doubles(x_object, &xb, 3 + 2 * count, 0, "x") < 0)
        return NULL;
    Py_ssize_t capacity = xb.len / 8;
    if (get_doubles(P_object, &Pb, capacity * capacity, 0, "P") < 0)
        goto release_x;
    if (Pb.len != capacity * capacity * 8) {
        PyErr_SetString(PyExc_ValueError, "P: expected a square array of x's capacity");
        goto release_P;
    }
    if (get_doubles(poses_object, &posesb, 3 * (row + 1), 1, "poses") < 0)
        goto release_P;
    if (get_doubles(covs_object, &covsb, 9 * (row + 1), 1, "pose_covs") < 0)
        goto release_poses;
    if (get_doubles(xy_object, &xyb, 2 * (start + count), 1, "map_xy") < 0)
        goto release_covs;
    if (get_doubles(map_covs_object, &mapb, 4 * (start + count), 1, "map_covs") < 0)
        goto release_xy;
    {
        const double *x = xb.buf, *P = Pb.buf;
        double *pose = (double *)posesb.buf + 3 * row;
        double *pose_cov = (double *)covsb.buf + 9 * row;
        memcpy(pose, x, 3 * sizeof(double));
        for (int i = 0; i < 3; ++i)
            memcpy(pose_cov + 3 * i, P + i * capacity, 3 * sizeof(double));
        memcpy((double *)xyb.buf + 2 * start, x + 3, 2 * count * sizeof(double));
        double *block = (double *)mapb.buf + 4 * start;
        for (Py_ssize_t k = 0; k < count; ++k, block += 4) {
            Py_ssize_t at = 3 + 2 * k; /* the landmark's first row and column in P */
            block[0] = P[at * capacity + at];
            block[1] = P[at * capacity + at + 1];
            block[2] = P[(at + 1) * capacity + at];
            block[3] = P[(at + 1) * capacity + at + 1];
        }
    }
    PyBuffer_Release(&mapb);
    PyBuffer_Release(&xyb);
    PyBuffer_Release(&covsb);
    PyBuffer_Release(&posesb);
    PyBuffer_Release(&Pb);
    PyBuffer_Release(&xb);
    Py_RETURN_NONE;
release_xy:
    PyBuffer_Release(&xyb);
release_covs:
    PyBuffer_Release(&covsb);
release_poses:
    PyBuffer_Release(&posesb);
release_P:
    PyBuffer_Release(&Pb);
release_x:
    PyBuffer_Release(&xb);
    return NULL;
}

static PyMethodDef methods[] = {
    {"copy_row", copy_row, METH_VARARGS, copy_row_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_rows", "A replay's row copies, compiled (see _rows.c).", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__rows(void)
{
    return PyModule_Create(&module);
}
