/* aobake._kernels, gutters: the dilation rings of aobake.post.dilate, compiled (its numpy
 * formulation is the reference: the same bits). */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>

/* dilate_rings(out, filled, height, width, channels, padding) -> rings filled
 *
 * aobake.post.dilate's rings, in place: out (H*W*C,) float64 the image (background zeroed),
 * filled (H*W,) bool.  A ring is every texel not filled with a filled 8-neighbour (as
 * filled before the ring); each becomes the mean of those neighbours, summed in the order
 * of aobake.post._NEIGHBOURS from 0.0 and divided by their count: the numpy formulation's
 * operations (tested bit for bit).  Ring texels are never a neighbour read in their own
 * ring (they are not filled yet), so they are written in place and marked after the ring.
 */
PyObject *dilate_rings(PyObject *self, PyObject *args)
{
    Py_buffer bout = {0}, bfill = {0};
    Py_ssize_t h, w, c, padding, rings = 0;
    int64_t *ring = NULL;
    PyObject *result = NULL;
    static const int DR[8] = {-1, -1, -1, 0, 0, 1, 1, 1}, DC[8] = {-1, 0, 1, -1, 1, -1, 0, 1};
    (void)self;
    if (!PyArg_ParseTuple(args, "w*w*nnnn", &bout, &bfill, &h, &w, &c, &padding))
        return NULL;
    if (h < 0 || w < 0 || c < 1 || padding < 0) {
        PyErr_SetString(PyExc_ValueError, "dilate_rings: bad shape or padding");
        goto done;
    }
    if (check(&bout, "out", 8, h * w * c) || check(&bfill, "filled", 1, h * w))
        goto done;
    ring = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(h * w + 1));
    if (!ring) {
        PyErr_NoMemory();
        goto done;
    }
    {
        double *out = bout.buf;
        uint8_t *filled = bfill.buf;
        Py_BEGIN_ALLOW_THREADS
        for (; rings < padding; ++rings) {
            Py_ssize_t k = 0;
            for (Py_ssize_t r = 0; r < h; ++r)
                for (Py_ssize_t col = 0; col < w; ++col) {
                    const Py_ssize_t t = r * w + col;
                    if (filled[t])
                        continue;
                    for (int j = 0; j < 8; ++j) {
                        const Py_ssize_t rr = r + DR[j], cc = col + DC[j];
                        if (rr >= 0 && rr < h && cc >= 0 && cc < w && filled[rr * w + cc]) {
                            ring[k++] = t;
                            break;
                        }
                    }
                }
            if (k == 0)
                break;
            for (Py_ssize_t i = 0; i < k; ++i) {
                const Py_ssize_t t = ring[i], r = t / w, col = t % w;
                double *dst = out + t * c;
                double count = 0.0;
                for (Py_ssize_t ch = 0; ch < c; ++ch)
                    dst[ch] = 0.0;
                for (int j = 0; j < 8; ++j) {
                    const Py_ssize_t rr = r + DR[j], cc = col + DC[j];
                    if (rr < 0 || rr >= h || cc < 0 || cc >= w || !filled[rr * w + cc])
                        continue;
                    const double *src = out + (rr * w + cc) * c;
                    for (Py_ssize_t ch = 0; ch < c; ++ch)
                        dst[ch] += src[ch];
                    count += 1.0;
                }
                for (Py_ssize_t ch = 0; ch < c; ++ch)
                    dst[ch] = dst[ch] / count;
            }
            for (Py_ssize_t i = 0; i < k; ++i)
                filled[ring[i]] = 1;
        }
        Py_END_ALLOW_THREADS
    }
    result = PyLong_FromSsize_t(rings);

done:
    PyMem_RawFree(ring);
    PyBuffer_Release(&bout); PyBuffer_Release(&bfill);
    return result;
}
