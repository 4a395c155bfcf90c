/* aobake._kernels, escape counts: the AO estimator's per-point counts of escaped rays
 * (aobake.quantities.ao), compiled. */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>

/* row_counts(flags, rows, m, out)
 *
 * flags (rows * m,) bool (one byte each, 0 or 1); out (rows,) int32 written: the
 * number of nonzero flags in each row of m.  The escape counts of the AO
 * estimator: numpy's count_nonzero over a short last axis costs as much as
 * generating the rays.
 */
PyObject *row_counts(PyObject *self, PyObject *args)
{
    Py_buffer fl = {0}, out = {0};
    Py_ssize_t rows, m;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*nnw*", &fl, &rows, &m, &out))
        return NULL;
    if (rows < 0 || m < 0) {
        PyErr_SetString(PyExc_ValueError, "negative size");
        goto done;
    }
    if (check(&fl, "flags", 1, rows * m) || check(&out, "out", 4, rows))
        goto done;
    {
        const uint8_t *f = (const uint8_t *)fl.buf;
        int32_t *c = (int32_t *)out.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = 0; r < rows; ++r) {
            int32_t total = 0;
            for (Py_ssize_t j = 0; j < m; ++j)
                total += f[r * m + j] != 0;
            c[r] = total;
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyBuffer_Release(&fl);
    PyBuffer_Release(&out);
    return result;
}
