/* How ekfviz's C modules (filters/_kernel.c, association/_search.c) take a float64
 * array. */
#ifndef EKFVIZ_DOUBLES_H
#define EKFVIZ_DOUBLES_H

#include <Python.h>
#include <string.h>

/* A C-contiguous float64 buffer of at least `count` doubles, writable if asked. */
static int get_doubles(PyObject *object, Py_buffer *view, Py_ssize_t count, int writable,
                       const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(object, view, flags) < 0)
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

#endif
