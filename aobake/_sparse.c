/* aobake._kernels, sparse systems: the Jacobi-preconditioned conjugate gradients of
 * aobake.sparse on a CSR matrix, compiled (aobake.sparse.cg_numpy is the reference,
 * operation for operation: the same bits, for any number of threads). */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>
#ifndef _WIN32
#include <pthread.h>
#endif

/* A barrier for the solve's threads (pthread_barrier_t is not on every platform). */
#ifndef _WIN32
typedef struct {
    pthread_mutex_t lock;
    pthread_cond_t turn;
    int count, waiting;
    unsigned generation;  /* wraps harmlessly: only equality is tested */
    int gate;  /* 0: the started threads wait; 1: go; -1: give up (a thread failed to start) */
} Barrier;

/* A started thread's first step: wait until all are started; 0 if they could not be. */
static int barrier_gate(Barrier *b)
{
    pthread_mutex_lock(&b->lock);
    while (b->gate == 0)
        pthread_cond_wait(&b->turn, &b->lock);
    const int go = b->gate > 0;
    pthread_mutex_unlock(&b->lock);
    return go;
}

static void barrier_open(Barrier *b, int gate)
{
    pthread_mutex_lock(&b->lock);
    b->gate = gate;
    pthread_cond_broadcast(&b->turn);
    pthread_mutex_unlock(&b->lock);
}

static void barrier_wait(Barrier *b)
{
    if (b->count <= 1)
        return;
    pthread_mutex_lock(&b->lock);
    const unsigned generation = b->generation;
    if (++b->waiting == b->count) {
        b->waiting = 0;
        ++b->generation;
        pthread_cond_broadcast(&b->turn);
    } else {
        while (generation == b->generation)
            pthread_cond_wait(&b->turn, &b->lock);
    }
    pthread_mutex_unlock(&b->lock);
}
#else
typedef struct { int count; } Barrier;
static void barrier_wait(Barrier *b) { (void)b; }
#endif

/* Checks a CSR pattern of n rows: indptr (n + 1,) from 0 to nnz, non-decreasing (with
 * `nonempty`, increasing: every row holds its diagonal), indices in 0..n-1; -1 with an
 * exception set. */
int aobake_check_csr(const int64_t *indptr, const int32_t *indices, Py_ssize_t n,
                     Py_ssize_t nnz, int nonempty)
{
    if (indptr[0] != 0 || indptr[n] != nnz) {
        PyErr_SetString(PyExc_ValueError, "indptr must run from 0 to nnz");
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; ++i)
        if (indptr[i] > indptr[i + 1] || (nonempty && indptr[i] == indptr[i + 1])) {
            PyErr_SetString(PyExc_ValueError, nonempty ? "a row without entries: not this pattern"
                                                       : "indptr must be non-decreasing");
            return -1;
        }
    for (Py_ssize_t j = 0; j < nnz; ++j)
        if (indices[j] < 0 || indices[j] >= n) {
            PyErr_SetString(PyExc_IndexError, "column out of range");
            return -1;
        }
    return 0;
}

/* The CG's threads: each its share of rows (split by entries), all running the same loop. */
typedef struct {
    const int64_t *indptr;
    const int32_t *indices;
    const double *data, *diag, *b, *rhs;
    Barrier *barrier;
    double *x, *r, *z, *p, *q;
    Py_ssize_t n, i0, i1;
    double tolerance;
    Py_ssize_t max_iterations;
    Py_ssize_t iterations;  /* out (the same in every thread) */
    double left;
} CsrWork;

/* out = A x on this thread's rows; returns after every thread's rows are done. */
static void csr_apply(const CsrWork *t, const double *x, double *out)
{
    for (Py_ssize_t i = t->i0; i < t->i1; ++i) {
        double s = 0.0;
        for (int64_t j = t->indptr[i]; j < t->indptr[i + 1]; ++j)
            s += t->data[j] * x[t->indices[j]];
        out[i] = s;
    }
    barrier_wait(t->barrier);
}

/* a . b summed in index order from the first product (numpy's cumsum of the reference) */
static double seq_dot(const double *a, const double *b, Py_ssize_t n)
{
    if (n == 0)
        return 0.0;
    double acc = a[0] * b[0];
    for (Py_ssize_t i = 1; i < n; ++i)
        acc += a[i] * b[i];
    return acc;
}

static double max_abs(const double *a, Py_ssize_t n)
{
    double m = 0.0;
    for (Py_ssize_t i = 0; i < n; ++i)
        if (fabs(a[i]) > m)
            m = fabs(a[i]);
    return m;
}

/* The whole conjugate-gradient loop, as every thread runs it on its rows.  The dot
 * products and the stopping test run over all rows in every thread (each ~0.1 ms), so the
 * threads take the same steps without one broadcasting them. */
static void csr_cg_share(CsrWork *t)
{
    const Py_ssize_t n = t->n, i0 = t->i0, i1 = t->i1;
    const double *diag = t->diag, *b = t->b, *rhs = t->rhs;
    double *x = t->x, *r = t->r, *z = t->z, *p = t->p, *q = t->q;
    for (Py_ssize_t i = i0; i < i1; ++i)
        x[i] = b[i];
    barrier_wait(t->barrier);
    csr_apply(t, x, q);
    for (Py_ssize_t i = i0; i < i1; ++i) {
        r[i] = rhs[i] - q[i];
        z[i] = r[i] / diag[i];
        p[i] = z[i];
    }
    barrier_wait(t->barrier);
    double rz = seq_dot(r, z, n);
    Py_ssize_t it = 0;
    while (max_abs(z, n) > t->tolerance && it < t->max_iterations) {
        csr_apply(t, p, q);
        const double alpha = rz / seq_dot(p, q, n);
        for (Py_ssize_t i = i0; i < i1; ++i) {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
            z[i] = r[i] / diag[i];
        }
        barrier_wait(t->barrier);
        const double rz_old = rz;
        rz = seq_dot(r, z, n);
        const double beta = rz / rz_old;
        /* every thread has read z (max_abs) and r, z (the dot) before p changes: p is read
         * only by the next csr_apply, after this barrier */
        for (Py_ssize_t i = i0; i < i1; ++i)
            p[i] = z[i] + beta * p[i];
        barrier_wait(t->barrier);
        ++it;
    }
    t->iterations = it;
    t->left = max_abs(z, n);
}

#ifndef _WIN32
static void *csr_cg_thread(void *arg)
{
    CsrWork *t = arg;
    Barrier *b = t->barrier;
    if (barrier_gate(b))
        csr_cg_share(t);
    return NULL;
}
#endif

/* seam_csr_cg(indptr, indices, data, diag, rhs, b, x, tolerance, max_iterations, threads)
 *     -> (iterations, the last max |r / diag|)
 *
 * Jacobi-preconditioned conjugate gradients on A x = rhs from x = b (A as seam_values
 * makes it, n rows), stopping when max |r / diag| <= tolerance or after max_iterations:
 * aobake.sparse.cg_numpy operation for operation (tested bit for bit), on
 * `threads` threads splitting the rows (the same bits for any number: every row's sum is
 * made by one thread, in column order). */
PyObject *seam_csr_cg(PyObject *self, PyObject *args)
{
    Py_buffer bptr = {0}, bidx = {0}, bdata = {0}, bdiag = {0}, brhs = {0}, bb = {0}, bx = {0};
    double tolerance;
    Py_ssize_t max_iterations, threads = 1, it = 0;
    double left = 0.0;
    double *scratch = NULL;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*w*dn|n", &bptr, &bidx, &bdata, &bdiag, &brhs, &bb,
                          &bx, &tolerance, &max_iterations, &threads))
        return NULL;
    {
        const Py_ssize_t n = bdiag.len / 8, nnz = bdata.len / 8;
        if (check(&bptr, "indptr", 8, n + 1) || check(&bidx, "indices", 4, nnz) ||
            check(&bdata, "data", 8, nnz) || check(&bdiag, "diag", 8, n) ||
            check(&brhs, "rhs", 8, n) || check(&bb, "b", 8, n) || check(&bx, "x", 8, n))
            goto done;
        if (threads < 1) {
            PyErr_SetString(PyExc_ValueError, "threads must be at least 1");
            goto done;
        }
        const int64_t *indptr = bptr.buf;
        const int32_t *indices = bidx.buf;
        if (aobake_check_csr(indptr, indices, n, nnz, 0) < 0)
            goto done;
        scratch = PyMem_RawMalloc(sizeof(double) * (size_t)(4 * n + 1));
        if (!scratch) {
            PyErr_NoMemory();
            goto done;
        }
#ifdef _WIN32
        threads = 1;
#endif
        if (threads > MAX_THREADS)
            threads = MAX_THREADS;
        CsrWork work[MAX_THREADS];
        Barrier barrier;
        barrier.count = (int)threads;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t k = 0; k < threads; ++k) {
            CsrWork t = {indptr, indices, bdata.buf, bdiag.buf, bb.buf, brhs.buf, &barrier,
                         bx.buf, scratch, scratch + n, scratch + 2 * n, scratch + 3 * n, n,
                         0, 0, tolerance, max_iterations, 0, 0.0};
            work[k] = t;
        }
        /* rows split by their entries: the first row whose entries start at or past k/T */
        for (Py_ssize_t k = 0, i = 0; k < threads; ++k) {
            work[k].i0 = i;
            const int64_t target = nnz * (k + 1) / threads;
            while (i < n && (k == threads - 1 || indptr[i] < target))
                ++i;
            work[k].i1 = i;
        }
#ifndef _WIN32
        if (threads > 1) {
            pthread_t handles[MAX_THREADS];
            Py_ssize_t started = 1;
            pthread_mutex_init(&barrier.lock, NULL);
            pthread_cond_init(&barrier.turn, NULL);
            barrier.waiting = barrier.generation = barrier.gate = 0;
            for (; started < threads; ++started)
                if (pthread_create(&handles[started], NULL, csr_cg_thread, &work[started]))
                    break;
            barrier_open(&barrier, started == threads ? 1 : -1);
            if (started == threads)
                csr_cg_share(&work[0]);
            for (Py_ssize_t k = 1; k < started; ++k)
                pthread_join(handles[k], NULL);
            pthread_mutex_destroy(&barrier.lock);
            pthread_cond_destroy(&barrier.turn);
            if (started < threads)  /* no threads to be had: all of it on this one */
                threads = barrier.count = 1;
        }
#endif
        if (threads == 1) {
            work[0].i0 = 0;
            work[0].i1 = n;
            csr_cg_share(&work[0]);
        }
        it = work[0].iterations;
        left = work[0].left;
        Py_END_ALLOW_THREADS
    }
    result = Py_BuildValue("nd", it, left);
done:
    PyMem_RawFree(scratch);
    PyBuffer_Release(&bptr); PyBuffer_Release(&bidx); PyBuffer_Release(&bdata);
    PyBuffer_Release(&bdiag); PyBuffer_Release(&brhs); PyBuffer_Release(&bb);
    PyBuffer_Release(&bx);
    return result;
}
