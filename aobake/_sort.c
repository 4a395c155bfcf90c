/* aobake._kernels, the stable argsort of aobake.rng.stable_argsort, compiled. */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>

/* radix_argsort(keys, bits, out_order, out_sorted)
 *
 * The stable argsort of keys (n,) uint32 below 2^bits (aobake.rng.stable_argsort: a stable
 * sort's permutation is unique, so the result is that of numpy's): a least-significant-digit
 * radix sort, 11 bits a pass.  out_order (n,) int64 the permutation, out_sorted (n,) uint32
 * keys[out_order], both written.
 */
#define RADIX_BITS 11
PyObject *radix_argsort(PyObject *self, PyObject *args)
{
    Py_buffer bk = {0}, bo = {0}, bs = {0};
    Py_ssize_t bits;
    uint32_t *tmp_key = NULL;
    int64_t *tmp_idx = NULL;
    Py_ssize_t *count = NULL;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*nw*w*", &bk, &bits, &bo, &bs))
        return NULL;
    {
        const Py_ssize_t n = bk.len / 4;
        if (bits < 0 || bits > 32) {
            PyErr_SetString(PyExc_ValueError, "bits must be in 0..32");
            goto done;
        }
        if (check(&bk, "keys", 4, n) || check(&bo, "out_order", 8, n) ||
            check(&bs, "out_sorted", 4, n))
            goto done;
        const uint32_t *keys = bk.buf;
        int64_t *order = bo.buf;
        uint32_t *sorted = bs.buf;
        const int passes = (int)((bits + RADIX_BITS - 1) / RADIX_BITS);
        if (bits < 32)
            for (Py_ssize_t i = 0; i < n; ++i)
                if (keys[i] >> bits) {
                    PyErr_SetString(PyExc_ValueError, "a key is not below 2^bits");
                    goto done;
                }
        tmp_key = PyMem_RawMalloc(sizeof(uint32_t) * (size_t)(n + 1));
        tmp_idx = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(n + 1));
        count = PyMem_RawMalloc(sizeof(Py_ssize_t) << RADIX_BITS);
        if (!tmp_key || !tmp_idx || !count) {
            PyErr_NoMemory();
            goto done;
        }
        Py_BEGIN_ALLOW_THREADS
        /* the pass that ends in the output buffers starts from the other pair */
        uint32_t *src_key = (passes % 2) ? tmp_key : sorted, *dst_key;
        int64_t *src_idx = (passes % 2) ? tmp_idx : order, *dst_idx;
        for (Py_ssize_t i = 0; i < n; ++i) {
            src_key[i] = keys[i];
            src_idx[i] = i;
        }
        for (int p = 0; p < passes; ++p) {
            const int shift = p * RADIX_BITS;
            const uint32_t mask = (1u << RADIX_BITS) - 1u;
            dst_key = src_key == sorted ? tmp_key : sorted;
            dst_idx = src_idx == order ? tmp_idx : order;
            for (int d = 0; d <= (int)mask; ++d)
                count[d] = 0;
            for (Py_ssize_t i = 0; i < n; ++i)
                ++count[(src_key[i] >> shift) & mask];
            Py_ssize_t at = 0;
            for (int d = 0; d <= (int)mask; ++d) {
                const Py_ssize_t c = count[d];
                count[d] = at;
                at += c;
            }
            for (Py_ssize_t i = 0; i < n; ++i) {  /* in input order: stable */
                const Py_ssize_t to = count[(src_key[i] >> shift) & mask]++;
                dst_key[to] = src_key[i];
                dst_idx[to] = src_idx[i];
            }
            src_key = dst_key;
            src_idx = dst_idx;
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyMem_RawFree(tmp_key);
    PyMem_RawFree(tmp_idx);
    PyMem_RawFree(count);
    PyBuffer_Release(&bk); PyBuffer_Release(&bo); PyBuffer_Release(&bs);
    return result;
}
