/* aobake._kernels, the parity union-find of aobake.repair._parity_union_find, compiled. */
#include "_kernels.h"
#include <stdint.h>
#include <string.h>

/* parity_union_find(a, b, odd, out_root, out_parity)
 *
 * aobake.repair._parity_union_find's rounds, one for one, so the result is its result bit
 * for bit (also the parities of a non-orientable component, which depend on the rounds):
 * a (e,) int64, b (e,) int64 edges between nodes 0..n-1, odd (e,) uint8 (bool) the parity
 * each edge asks for; out_root (n,) int64 (n is its length) and out_parity (n,) uint8,
 * both written.  A round: every tree is flattened (a node's parent is below it, so one
 * pass in node order does what the numpy's pointer jumping does: parent = root, parity =
 * the xor of the steps to it); the edges within one tree are dropped; each root with an
 * edge to another tree hooks onto the smallest root it reaches, ties to the lexically
 * first (root, parity), the parity being parity[a] ^ parity[b] ^ odd of that edge.
 */
PyObject *parity_union_find(PyObject *self, PyObject *args)
{
    Py_buffer ba = {0}, bb = {0}, bo = {0}, br = {0}, bp = {0};
    int64_t *la = NULL, *lb = NULL, *best = NULL, *touched = NULL;
    uint8_t *lo = NULL, *best_parity = NULL;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*w*w*", &ba, &bb, &bo, &br, &bp))
        return NULL;
    {
        const Py_ssize_t e = ba.len / 8, n = br.len / 8;
        if (check(&ba, "a", 8, e) || check(&bb, "b", 8, e) || check(&bo, "odd", 1, e) ||
            check(&br, "out_root", 8, n) || check(&bp, "out_parity", 1, n))
            goto done;
        const int64_t *a = ba.buf, *b = bb.buf;
        const uint8_t *odd = bo.buf;
        for (Py_ssize_t i = 0; i < e; ++i)
            if (a[i] < 0 || a[i] >= n || b[i] < 0 || b[i] >= n) {
                PyErr_SetString(PyExc_ValueError, "an edge's node is not in 0..n-1");
                goto done;
            }
        la = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(e + 1));
        lb = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(e + 1));
        lo = PyMem_RawMalloc((size_t)(e + 1));
        best = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(n + 1));
        touched = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(n + 1));
        best_parity = PyMem_RawMalloc((size_t)(n + 1));
        if (!la || !lb || !lo || !best || !touched || !best_parity) {
            PyErr_NoMemory();
            goto done;
        }
        int64_t *parent = br.buf;
        uint8_t *parity = bp.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t x = 0; x < n; ++x) {
            parent[x] = x;
            parity[x] = 0;
            best[x] = -1;
        }
        for (Py_ssize_t i = 0; i < e; ++i) {
            la[i] = a[i];
            lb[i] = b[i];
            lo[i] = odd[i] ? 1 : 0;
        }
        Py_ssize_t live = e;
        for (;;) {
            /* flatten: parent[x] <= x (roots hook only onto smaller roots), so parent[x]
             * is flat by the time x is reached; a root's parity is 0 */
            for (Py_ssize_t x = 0; x < n; ++x) {
                const int64_t p = parent[x];
                parity[x] ^= parity[p];
                parent[x] = parent[p];
            }
            Py_ssize_t kept = 0, n_touched = 0;
            for (Py_ssize_t i = 0; i < live; ++i) {
                const int64_t ra = parent[la[i]], rb = parent[lb[i]];
                if (ra == rb)
                    continue;  /* within one tree for good */
                la[kept] = la[i];
                lb[kept] = lb[i];
                lo[kept] = lo[i];
                ++kept;
                const uint8_t between = parity[la[i]] ^ parity[lb[i]] ^ lo[i];
                const int64_t high = ra > rb ? ra : rb, low = ra > rb ? rb : ra;
                if (best[high] < 0) {
                    touched[n_touched++] = high;
                    best[high] = low;
                    best_parity[high] = between;
                } else if (low < best[high] || (low == best[high] && between < best_parity[high])) {
                    best[high] = low;
                    best_parity[high] = between;
                }
            }
            live = kept;
            if (!live)
                break;
            for (Py_ssize_t t = 0; t < n_touched; ++t) {
                const int64_t high = touched[t];
                parent[high] = best[high];
                parity[high] = best_parity[high];
                best[high] = -1;
            }
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyMem_RawFree(la);
    PyMem_RawFree(lb);
    PyMem_RawFree(lo);
    PyMem_RawFree(best);
    PyMem_RawFree(touched);
    PyMem_RawFree(best_parity);
    PyBuffer_Release(&ba); PyBuffer_Release(&bb); PyBuffer_Release(&bo);
    PyBuffer_Release(&br); PyBuffer_Release(&bp);
    return result;
}
