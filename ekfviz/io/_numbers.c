/* A block of a numeric log converted at once, compiled (see ekfviz/io/text.py).
 *
 * A long log is mostly numbers: the 102,000-step classic log holds 1.4 million. Python
 * converts them one float() at a time (0.3 s), and counting the numbers of each line in
 * numpy costs a third as much again. This does both in one pass over the bytes, with the
 * C library's strtod: correctly rounded, as float() is, so the values are the same bits.
 *
 * The caller hands only blocks whose bytes are plain decimal numbers, separators and line
 * ends (text.py's _PLAIN_BYTES), so strtod cannot meet the words it would also take
 * ("inf", "nan", hexadecimal). A token it does not take whole ("1.2.3", "e5", "-") makes
 * the call say so, and the caller reads the block line by line, with its messages.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <locale.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

PyDoc_STRVAR(parse_doc,
"parse(data, lines, values, counts, digits=None) -> int\n\n"
"The numbers of `data` (bytes: `lines` lines joined by LF, numbers separated by spaces\n"
"and tabs) into `values` (writable float64, room for len(data) // 2 + 1), and how many\n"
"each line holds into `counts` (writable int64, `lines` long); where `digits` is given\n"
"(writable uint8, as long as `values`), 1 for each number written as ASCII digits alone\n"
"(an integer as written: not '+5', '5.0' or '5e0'), else 0. Returns how many numbers\n"
"it wrote, or -1 where a token is not a number as a whole (or the locale's decimal\n"
"point is not '.'); `values`, `counts` and `digits` are then not to be read.");

static PyObject *parse(PyObject *self, PyObject *args)
{
    const char *data;
    Py_ssize_t size, lines;
    PyObject *values_object, *counts_object, *digits_object = Py_None;
    if (!PyArg_ParseTuple(args, "y#nOO|O", &data, &size, &lines, &values_object, &counts_object,
                          &digits_object))
        return NULL;
    Py_buffer vb, cb, db = {0};
    if (PyObject_GetBuffer(values_object, &vb, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT)
        < 0)
        return NULL;
    if (PyObject_GetBuffer(counts_object, &cb, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT)
        < 0) {
        PyBuffer_Release(&vb);
        return NULL;
    }
    if (digits_object != Py_None &&
        PyObject_GetBuffer(digits_object, &db, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT)
            < 0) {
        PyBuffer_Release(&vb);
        PyBuffer_Release(&cb);
        return NULL;
    }
    Py_ssize_t written = -1;
    if (vb.itemsize != 8 || vb.format == NULL || strcmp(vb.format, "d") != 0 ||
        vb.len / 8 < size / 2 + 1 || cb.itemsize != 8 || cb.format == NULL ||
        (strcmp(cb.format, "l") != 0 && strcmp(cb.format, "q") != 0) || cb.len / 8 < lines ||
        (db.obj != NULL && (db.itemsize != 1 || db.format == NULL || strcmp(db.format, "B") != 0 ||
                            db.len < size / 2 + 1))) {
        PyErr_SetString(PyExc_ValueError,
                        "values: expected float64 of len(data) // 2 + 1, counts: int64 of lines,"
                        " digits: uint8 as long as values");
        goto release;
    }
    const struct lconv *conventions = localeconv();
    if (conventions->decimal_point == NULL || strcmp(conventions->decimal_point, ".") != 0)
        goto done; /* strtod would read another decimal point: the caller converts */
    double *values = vb.buf;
    int64_t *counts = cb.buf;
    uint8_t *digits = db.obj != NULL ? db.buf : NULL;
    memset(counts, 0, (size_t)lines * sizeof(int64_t));
    Py_ssize_t line = 0, count = 0;
    const char *at = data, *end = data + size;
    while (at < end) {
        char c = *at;
        if (c == ' ' || c == '\t') {
            ++at;
            continue;
        }
        if (c == '\n') {
            ++line;
            ++at;
            continue;
        }
        if (line >= lines)
            goto done; /* more lines than said */
        char *stop;
        /* the bytes object ends in NUL: strtod stops there at the latest */
        double value = strtod(at, &stop);
        if (stop == at || (stop < end && *stop != ' ' && *stop != '\t' && *stop != '\n'))
            goto done; /* not a number as a whole */
        if (value == 0.0) { /* a digit other than 0 before the exponent: it underflowed */
            for (const char *c = at; c < stop && *c != 'e' && *c != 'E'; ++c)
                if (*c >= '1' && *c <= '9')
                    goto done; /* the caller reads it line by line, to name it */
        }
        if (digits != NULL) {
            const char *c = at;
            while (c < stop && *c >= '0' && *c <= '9')
                ++c;
            digits[count] = c == stop;
        }
        values[count++] = value;
        counts[line] += 1;
        at = stop;
    }
    written = count;
done:;
    PyObject *result = PyLong_FromSsize_t(written);
    PyBuffer_Release(&vb);
    PyBuffer_Release(&cb);
    if (db.obj != NULL)
        PyBuffer_Release(&db);
    return result;
release:
    PyBuffer_Release(&vb);
    PyBuffer_Release(&cb);
    if (db.obj != NULL)
        PyBuffer_Release(&db);
    return NULL;
}

static PyMethodDef methods[] = {
    {"parse", parse, METH_VARARGS, parse_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_numbers",
    "A block of a numeric log converted at once, compiled (see _numbers.c).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__numbers(void)
{
    return PyModule_Create(&module);
}
