/* aobake._kernels, the seam erasure (aobake.targets.texels.seams): its normal matrix
 * A = W + P^T S P over the covered unknowns, assembled once (seam_pattern, then
 * seam_values), for the conjugate gradients on it (seam_csr_cg, _sparse.c): each iteration
 * is then one pass over a CSR matrix, where the operator applied as the points (the fill,
 * the group sums, their scatter, the fill's transpose: four passes of random reads) took
 * three times as long (the bunny's 114k unknowns: ~10 -> ~3 ms an iteration).
 *
 * aobake.targets.texels.seams._assemble_numpy is the reference, operation for operation
 * (tested bit for bit):
 *   block[g][k][l] = sum over the group's points p, in order, of (lam_p c_pk) c_pl;
 *   a slot's texel t maps to the unknowns map(t): itself (weight 1) when covered, else
 *   its fill entries (fill_from, fill_weight, in entry order);
 *   A_ab = the sum, from 0.0 in the order of generation (g, k, a's entry, l, b's entry),
 *   of (block[g][k][l] w_a) w_b, then + 0.0 (every diagonal is stored), then the
 *   diagonal's + w_a. */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>
#ifndef _WIN32
#include <pthread.h>
#endif

/* ptr (n + 1,) and list (len,): for each target i, the entries e with target[e] == i in
 * ascending e (a counting sort; ptr must be zeroed).  target[e] in 0..n-1. */
static void gather_lists(const int64_t *target, Py_ssize_t len, Py_ssize_t n, int64_t *ptr,
                         int64_t *list)
{
    for (Py_ssize_t e = 0; e < len; ++e)
        ++ptr[target[e] + 1];
    for (Py_ssize_t i = 0; i < n; ++i)
        ptr[i + 1] += ptr[i];
    for (Py_ssize_t e = 0; e < len; ++e)
        list[ptr[target[e]]++] = e;
    for (Py_ssize_t i = n; i > 0; --i)  /* ptr[i] ran to the end of list i: shift back */
        ptr[i] = ptr[i - 1];
    ptr[0] = 0;
}

/* The unknowns' maps of seam_pattern and seam_values: slot j's texel t maps to its unknown
 * (weight 1) when covered, else to its fill entries to_list[to_ptr[t] ..] (fill_from's
 * unknowns, fill_weight). */
typedef struct {
    const int64_t *slots, *from, *cidx, *to_ptr, *to_list;
    const uint8_t *gutter;
    const double *fw;
} Maps;

/* Row a's columns, in order of first touch, into cols (mark[b] == a once touched); the
 * diagonal always among them.  Returns their count. */
static Py_ssize_t row_columns(const Maps *M, const int64_t *in_ptr, const int64_t *in_j,
                              Py_ssize_t a, int32_t *mark, int32_t *cols)
{
    Py_ssize_t count = 0;
    for (int64_t q = in_ptr[a]; q < in_ptr[a + 1]; ++q) {
        const int64_t *s = M->slots + 8 * (in_j[q] / 8);
        for (int l = 0; l < 8; ++l) {
            const int64_t t = s[l];
            if (!M->gutter[t]) {
                const int64_t b = M->cidx[t];
                if (mark[b] != (int32_t)a) {
                    mark[b] = (int32_t)a;
                    cols[count++] = (int32_t)b;
                }
                continue;
            }
            for (int64_t qq = M->to_ptr[t]; qq < M->to_ptr[t + 1]; ++qq) {
                const int64_t b = M->cidx[M->from[M->to_list[qq]]];
                if (mark[b] != (int32_t)a) {
                    mark[b] = (int32_t)a;
                    cols[count++] = (int32_t)b;
                }
            }
        }
    }
    if (mark[a] != (int32_t)a) {
        mark[a] = (int32_t)a;
        cols[count++] = (int32_t)a;
    }
    return count;
}

/* data[position of (a, b)] += term: (a, b) is in the pattern; a branch-free binary search
 * in row a's ascending columns (a branching one mispredicted at every step). */
static inline void add_at(const int64_t *indptr, const int32_t *indices, double *data,
                          int64_t a, int32_t b, double term)
{
    const int32_t *base = indices + indptr[a];
    int64_t len = indptr[a + 1] - indptr[a];
    while (len > 1) {
        const int64_t half = len / 2;
        base = base[half] <= b ? base + half : base;
        len -= half;
    }
    data[base - indices] += term;
}

/* One thread's rows r0 .. r1 - 1 of seam_pattern or seam_values: their pattern (pass 0: cols,
 * ascending
 * per row, counts[a] each row's count) or their values (pass 1: every group read in order,
 * only its terms of these rows added). */
typedef struct {
    const Maps *M;
    const int64_t *in_ptr, *in_j, *starts, *indptr;
    const int32_t *indices;
    const double *coef, *lam;
    double *data;
    Py_ssize_t groups, r0, r1, nnz, capacity;
    int32_t *mark, *cols, *row_cols;
    int64_t *counts;
    int pass, failed;
} AssembleWork;

static void assemble_pattern(AssembleWork *t)
{
    for (Py_ssize_t a = t->r0; a < t->r1; ++a) {
        const Py_ssize_t count = row_columns(t->M, t->in_ptr, t->in_j, a, t->mark, t->row_cols);
        int32_t *cols = t->row_cols;
        for (Py_ssize_t u = 1; u < count; ++u) {  /* a row holds a few dozen */
            const int32_t c = cols[u];
            Py_ssize_t v = u;
            for (; v > 0 && cols[v - 1] > c; --v)
                cols[v] = cols[v - 1];
            cols[v] = c;
        }
        if (t->nnz + count > t->capacity) {
            const Py_ssize_t grown = 2 * (t->nnz + count) + 1024;
            int32_t *more = PyMem_RawRealloc(t->cols, sizeof(int32_t) * (size_t)grown);
            if (!more) {
                t->failed = 1;
                return;
            }
            t->cols = more;
            t->capacity = grown;
        }
        memcpy(t->cols + t->nnz, cols, sizeof(int32_t) * (size_t)count);
        t->nnz += count;
        t->counts[a] = count;
    }
}

static void assemble_values(AssembleWork *t)
{
    const Maps *M = t->M;
    const int64_t *slots = M->slots, *to_ptr = M->to_ptr, *to_list = M->to_list;
    const int64_t *cidx = M->cidx, *from = M->from;
    const uint8_t *gutter = M->gutter;
    const double *fw = M->fw;
    for (Py_ssize_t g = 0; g < t->groups; ++g) {
        double block[64];
        for (int q = 0; q < 64; ++q)
            block[q] = 0.0;
        for (int64_t p = t->starts[g]; p < t->starts[g + 1]; ++p) {
            const double *c = t->coef + 8 * p;
            for (int k = 0; k < 8; ++k) {
                const double lk = t->lam[p] * c[k];
                for (int l = 0; l < 8; ++l)
                    block[8 * k + l] += lk * c[l];
            }
        }
        const int64_t *s = slots + 8 * g;
        for (int k = 0; k < 8; ++k) {
            const int64_t ta = s[k];
            const int64_t qa0 = gutter[ta] ? to_ptr[ta] : -1;
            const int64_t qa1 = gutter[ta] ? to_ptr[ta + 1] : 0;
            for (int64_t qa = qa0; qa < qa1; ++qa) {
                const int64_t ea = qa < 0 ? -1 : to_list[qa];
                const int64_t a = ea < 0 ? cidx[ta] : cidx[from[ea]];
                if (a < t->r0 || a >= t->r1)
                    continue;  /* another thread's row */
                const double wa = ea < 0 ? 1.0 : fw[ea];
                for (int l = 0; l < 8; ++l) {
                    const int64_t tb = s[l];
                    const double bk = block[8 * k + l] * wa;
                    if (!gutter[tb]) {
                        add_at(t->indptr, t->indices, t->data, a, (int32_t)cidx[tb], bk * 1.0);
                        continue;
                    }
                    for (int64_t qb = to_ptr[tb]; qb < to_ptr[tb + 1]; ++qb) {
                        const int64_t eb = to_list[qb];
                        add_at(t->indptr, t->indices, t->data, a, (int32_t)cidx[from[eb]],
                               bk * fw[eb]);
                    }
                }
            }
        }
    }
}

static void *assemble_thread(void *arg)
{
    AssembleWork *t = arg;
    if (t->pass == 0)
        assemble_pattern(t);
    else
        assemble_values(t);
    return NULL;
}

/* Run `threads` AssembleWork shares (on threads where they can be had: one that cannot
 * start runs on this one, after the others; the shares, not the threads, make the bits). */
static void assemble_run(AssembleWork *work, Py_ssize_t threads)
{
#ifndef _WIN32
    pthread_t handles[MAX_THREADS];
    int started[MAX_THREADS] = {0};
    for (Py_ssize_t k = 1; k < threads; ++k)
        started[k] = pthread_create(&handles[k], NULL, assemble_thread, &work[k]) == 0;
    assemble_thread(&work[0]);
    for (Py_ssize_t k = 1; k < threads; ++k) {
        if (started[k])
            pthread_join(handles[k], NULL);
        else
            assemble_thread(&work[k]);
    }
#else
    for (Py_ssize_t k = 0; k < threads; ++k)
        assemble_thread(&work[k]);
#endif
}

/* The arrays seam_pattern and seam_values both derive from a system: each unknown's number
 * (cidx, -1 for a gutter texel), each unknown's texel, and each gutter texel's fill entries
 * (to_ptr / to_list). */
typedef struct {
    int64_t *ints;  /* one allocation: cidx (n), texel (n), to_ptr (n + 1), to_list (fills) */
    int64_t *cidx, *texel, *to_ptr, *to_list;
    Py_ssize_t nc;
} Numbering;

/* Checks the system's index arrays and numbers its unknowns; -1 with an exception set. */
static int seam_numbering(Py_buffer *bstarts, Py_buffer *bslots, Py_buffer *bgut, Py_buffer *bto,
                          Py_buffer *bfrom, Py_ssize_t m, Numbering *out)
{
    const Py_ssize_t n = bgut->len, groups = bslots->len / 64, fills = bto->len / 8;
    if (check(bstarts, "starts", 8, groups + 1) || check(bslots, "slots", 8, 8 * groups) ||
        check(bgut, "gutter", 1, n) || check(bto, "fill_to", 8, fills) ||
        check(bfrom, "fill_from", 8, fills))
        return -1;
    const int64_t *starts = bstarts->buf, *slots = bslots->buf, *to = bto->buf, *from = bfrom->buf;
    const uint8_t *gutter = bgut->buf;
    if (starts[0] != 0 || (m >= 0 && starts[groups] != m)) {
        PyErr_SetString(PyExc_ValueError, "starts must run from 0 to m");
        return -1;
    }
    for (Py_ssize_t g = 0; g < groups; ++g)
        if (starts[g] > starts[g + 1]) {
            PyErr_SetString(PyExc_ValueError, "starts must be non-decreasing");
            return -1;
        }
    for (Py_ssize_t i = 0; i < 8 * groups; ++i)
        if (slots[i] < 0 || slots[i] >= n) {
            PyErr_SetString(PyExc_IndexError, "slot out of range");
            return -1;
        }
    for (Py_ssize_t e = 0; e < fills; ++e)
        if (to[e] < 0 || to[e] >= n || from[e] < 0 || from[e] >= n || !gutter[to[e]] ||
            gutter[from[e]]) {
            PyErr_SetString(PyExc_IndexError,
                            "a fill entry must take a covered texel into a gutter one");
            return -1;
        }
    if (n >= INT32_MAX) {
        PyErr_SetString(PyExc_ValueError, "too many unknowns");
        return -1;
    }
    out->ints = PyMem_RawCalloc((size_t)(3 * n + 1 + fills + 1), sizeof(int64_t));
    if (!out->ints) {
        PyErr_NoMemory();
        return -1;
    }
    out->cidx = out->ints;
    out->texel = out->cidx + n;
    out->to_ptr = out->texel + n;
    out->to_list = out->to_ptr + (n + 1);
    Py_ssize_t nc = 0;
    for (Py_ssize_t i = 0; i < n; ++i) {
        out->cidx[i] = gutter[i] ? -1 : nc;
        if (!gutter[i])
            out->texel[nc++] = i;
    }
    out->nc = nc;
    gather_lists(to, fills, n, out->to_ptr, out->to_list);
    return 0;
}

static Py_ssize_t clamp_threads(Py_ssize_t threads, Py_ssize_t rows)
{
    if (threads > MAX_THREADS)
        threads = MAX_THREADS;
    if (threads > rows)
        threads = rows > 0 ? rows : 1;
    return threads;
}

/* seam_pattern(starts, slots, gutter, fill_to, fill_from, threads=1) -> (indptr, indices)
 *
 * The pattern of the seam erasure's normal matrix A = W + P^T S P over the covered unknowns
 * (numbered in texel order, skipping the gutter ones): indptr (nc + 1,) int64 and indices
 * (nnz,) int32 bytes, each row's columns ascending, every diagonal stored.  It depends on
 * the system only, not on the baked values, so the seam system's thread makes it while the
 * samples are traced.  starts (G + 1,) int64 the groups' first points, slots (G, 8) int64 in
 * 0..n-1, gutter (n,) bool, fill_* (e,) int64 (fill_to a gutter texel, fill_from a covered
 * one).  Rows split over `threads` (the same pattern for any number). */
PyObject *seam_pattern(PyObject *self, PyObject *args)
{
    Py_buffer bstarts = {0}, bslots = {0}, bgut = {0}, bto = {0}, bfrom = {0};
    Py_ssize_t threads = 1;
    Numbering N = {0};
    int64_t *in_j = NULL, *in_ptr = NULL, *indptr = NULL;
    PyObject *result = NULL, *pi = NULL, *px = NULL;
    AssembleWork work[MAX_THREADS];
    Py_ssize_t shares = 0;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*|n", &bstarts, &bslots, &bgut, &bto, &bfrom, &threads))
        return NULL;
    if (threads < 1) {
        PyErr_SetString(PyExc_ValueError, "threads must be at least 1");
        goto done;
    }
    if (seam_numbering(&bstarts, &bslots, &bgut, &bto, &bfrom, -1, &N) < 0)
        goto done;
    {
        const Py_ssize_t groups = bslots.len / 64, nc = N.nc;
        const int64_t *slots = bslots.buf, *from = bfrom.buf;
        const uint8_t *gutter = bgut.buf;
        const int64_t *cidx = N.cidx, *to_ptr = N.to_ptr, *to_list = N.to_list;
        Py_ssize_t incoming = 0;  /* (slot, unknown) pairs over all slots' maps */
        for (Py_ssize_t j = 0; j < 8 * groups; ++j) {
            const int64_t t = slots[j];
            incoming += gutter[t] ? to_ptr[t + 1] - to_ptr[t] : 1;
        }
        in_ptr = PyMem_RawCalloc((size_t)(nc + 2), sizeof(int64_t));
        in_j = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(incoming + 1));
        indptr = PyMem_RawCalloc((size_t)(nc + 1), sizeof(int64_t));
        if (!in_ptr || !in_j || !indptr) {
            PyErr_NoMemory();
            goto done;
        }
        const Maps M = {slots, from, cidx, to_ptr, to_list, gutter, NULL};
        Py_BEGIN_ALLOW_THREADS
        /* per unknown a, the slots j whose map holds it, ascending j (a counting sort of
         * the (j, a) pairs, made in ascending j) */
        for (int pass = 0; pass < 2; ++pass) {
            for (Py_ssize_t j = 0; j < 8 * groups; ++j) {
                const int64_t t = slots[j];
                if (!gutter[t]) {
                    const int64_t a = cidx[t];
                    if (pass == 0) ++in_ptr[a + 1]; else in_j[in_ptr[a]++] = j;
                    continue;
                }
                for (int64_t q = to_ptr[t]; q < to_ptr[t + 1]; ++q) {
                    const int64_t a = cidx[from[to_list[q]]];
                    if (pass == 0) ++in_ptr[a + 1]; else in_j[in_ptr[a]++] = j;
                }
            }
            if (pass == 0)
                for (Py_ssize_t a = 0; a < nc; ++a)
                    in_ptr[a + 1] += in_ptr[a];
        }
        for (Py_ssize_t a = nc; a > 0; --a)  /* in_ptr[a] ran to the end of list a */
            in_ptr[a] = in_ptr[a - 1];
        in_ptr[0] = 0;
        Py_END_ALLOW_THREADS
        /* each share's rows on a thread (rows split by their incoming slots) */
        shares = clamp_threads(threads, nc);
        int failed = 0;
        for (Py_ssize_t k = 0, a = 0; k < shares; ++k) {
            AssembleWork t = {&M, in_ptr, in_j, NULL, NULL, NULL, NULL, NULL, NULL, groups,
                              a, a, 0, 0, NULL, NULL, NULL, NULL, 0, 0};
            const int64_t target = in_ptr[nc] * (k + 1) / shares;
            while (a < nc && (k == shares - 1 || in_ptr[a] < target))
                ++a;
            t.r1 = a;
            t.mark = PyMem_RawMalloc(sizeof(int32_t) * (size_t)(nc + 1));
            t.row_cols = PyMem_RawMalloc(sizeof(int32_t) * (size_t)(nc + 1));
            t.counts = indptr + 1;  /* each row's count, summed in place below */
            failed |= !t.mark || !t.row_cols;
            work[k] = t;
        }
        if (!failed) {
            Py_BEGIN_ALLOW_THREADS
            for (Py_ssize_t k = 0; k < shares; ++k)
                for (Py_ssize_t b = 0; b < nc; ++b)
                    work[k].mark[b] = -1;
            assemble_run(work, shares);
            Py_END_ALLOW_THREADS
            for (Py_ssize_t k = 0; k < shares; ++k)
                failed |= work[k].failed;
        }
        if (failed) {
            PyErr_NoMemory();
            goto done;
        }
        for (Py_ssize_t a = 0; a < nc; ++a)
            indptr[a + 1] += indptr[a];
        const Py_ssize_t nnz = indptr[nc];
        px = PyBytes_FromStringAndSize(NULL, 4 * nnz);
        pi = PyBytes_FromStringAndSize((const char *)indptr, 8 * (nc + 1));
        if (!px || !pi)
            goto done;
        int32_t *indices = (int32_t *)PyBytes_AS_STRING(px);
        for (Py_ssize_t k = 0; k < shares; ++k)
            if (work[k].nnz)
                memcpy(indices + indptr[work[k].r0], work[k].cols,
                       sizeof(int32_t) * (size_t)work[k].nnz);
        result = Py_BuildValue("(OO)", pi, px);
    }
done:
    for (Py_ssize_t k = 0; k < shares; ++k) {
        PyMem_RawFree(work[k].mark);
        PyMem_RawFree(work[k].row_cols);
        PyMem_RawFree(work[k].cols);
    }
    Py_XDECREF(pi); Py_XDECREF(px);
    PyMem_RawFree(N.ints); PyMem_RawFree(in_ptr); PyMem_RawFree(in_j); PyMem_RawFree(indptr);
    PyBuffer_Release(&bstarts); PyBuffer_Release(&bslots); PyBuffer_Release(&bgut);
    PyBuffer_Release(&bto); PyBuffer_Release(&bfrom);
    return result;
}

/* seam_values(coef, lam, starts, slots, gutter, fill_to, fill_from, fill_weight, w, indptr,
 *             indices, threads=1) -> data (nnz,) float64 bytes
 *
 * The values of A on seam_pattern's pattern (indptr, indices), in the arithmetic of
 * aobake.targets.texels.seams._assemble_numpy: coef (m, 8), lam (m,) float64, w (n,)
 * float64, the rest as for seam_pattern.  Every share reads the groups in order and adds its
 * own rows' terms (each group's block made just before its terms), so every entry's sum is
 * the reference's whatever the number of threads. */
PyObject *seam_values(PyObject *self, PyObject *args)
{
    Py_buffer bcoef = {0}, blam = {0}, bstarts = {0}, bslots = {0}, bgut = {0};
    Py_buffer bto = {0}, bfrom = {0}, bfw = {0}, bw = {0}, bptr = {0}, bidx = {0};
    Py_ssize_t threads = 1;
    Numbering N = {0};
    PyObject *result = NULL, *pd = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*y*|n", &bcoef, &blam, &bstarts, &bslots,
                          &bgut, &bto, &bfrom, &bfw, &bw, &bptr, &bidx, &threads))
        return NULL;
    if (threads < 1) {
        PyErr_SetString(PyExc_ValueError, "threads must be at least 1");
        goto done;
    }
    {
        const Py_ssize_t m = blam.len / 8, n = bgut.len, fills = bto.len / 8;
        if (check(&bcoef, "coef", 8, 8 * m) || check(&blam, "lam", 8, m) ||
            check(&bfw, "fill_weight", 8, fills) || check(&bw, "w", 8, n) ||
            seam_numbering(&bstarts, &bslots, &bgut, &bto, &bfrom, m, &N) < 0)
            goto done;
        const Py_ssize_t nc = N.nc, groups = bslots.len / 64, nnz = bidx.len / 4;
        if (check(&bptr, "indptr", 8, nc + 1) || check(&bidx, "indices", 4, nnz))
            goto done;
        const int64_t *indptr = bptr.buf;
        const int32_t *indices = bidx.buf;
        if (aobake_check_csr(indptr, indices, nc, nnz, 1) < 0)  /* every row holds its diagonal */
            goto done;
        pd = PyBytes_FromStringAndSize(NULL, 8 * nnz);
        if (!pd)
            goto done;
        double *data = (double *)PyBytes_AS_STRING(pd);
        const Maps M = {bslots.buf, bfrom.buf, N.cidx, N.to_ptr, N.to_list, bgut.buf, bfw.buf};
        const Py_ssize_t shares = clamp_threads(threads, nc);
        AssembleWork work[MAX_THREADS];
        for (Py_ssize_t k = 0; k < shares; ++k) {
            AssembleWork t = {&M, NULL, NULL, bstarts.buf, indptr, indices, bcoef.buf, blam.buf,
                              data, groups, nc * k / shares, nc * (k + 1) / shares, 0, 0,
                              NULL, NULL, NULL, NULL, 1, 0};
            work[k] = t;
        }
        const double *w = bw.buf;
        const int64_t *texel = N.texel;
        int missing = 0;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t u = 0; u < nnz; ++u)
            data[u] = 0.0;
        assemble_run(work, shares);
        /* the diagonal: + 0.0 (the reference's entry that makes sure it is stored), + w */
        for (Py_ssize_t a = 0; a < nc; ++a) {
            int64_t u = indptr[a];
            while (u < indptr[a + 1] && indices[u] != a)
                ++u;
            if (u == indptr[a + 1])
                missing = 1;
            else
                data[u] = (data[u] + 0.0) + w[texel[a]];
        }
        Py_END_ALLOW_THREADS
        if (missing) {
            PyErr_SetString(PyExc_ValueError, "a row without its diagonal: not this pattern");
            goto done;
        }
        result = pd;
        pd = NULL;
    }
done:
    Py_XDECREF(pd);
    PyMem_RawFree(N.ints);
    PyBuffer_Release(&bcoef); PyBuffer_Release(&blam); PyBuffer_Release(&bstarts);
    PyBuffer_Release(&bslots); PyBuffer_Release(&bgut); PyBuffer_Release(&bto);
    PyBuffer_Release(&bfrom); PyBuffer_Release(&bfw); PyBuffer_Release(&bw);
    PyBuffer_Release(&bptr); PyBuffer_Release(&bidx);
    return result;
}
