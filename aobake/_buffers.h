/* Shared by aobake/_kernels.c and aobake/_pack.c (one extension, two sources). */
#ifndef AOBAKE_BUFFERS_H
#define AOBAKE_BUFFERS_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

/* Check a buffer: C-contiguous, given item size, exactly `count` items. */
static inline int check(Py_buffer *b, const char *name, Py_ssize_t itemsize, Py_ssize_t count)
{
    if (!PyBuffer_IsContiguous(b, 'C')) {
        PyErr_Format(PyExc_ValueError, "%s must be C-contiguous", name);
        return -1;
    }
    if (b->itemsize != itemsize || b->len != itemsize * count) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd items of %zd bytes, got %zd bytes",
                     name, count, itemsize, b->len);
        return -1;
    }
    return 0;
}

#endif
