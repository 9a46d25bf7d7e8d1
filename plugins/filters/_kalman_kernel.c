/* Compiled covariance arithmetic of the Kalman filters (plugins/filters/ekf.py, base.py):
 *
 *   propagate  the EKF's chain over a run of input samples,  P <- F_j P F_j^T + Q_j  (then symmetric)
 *   update     the EKF / KF update about one linearisation point (base.linearised_update, one iteration):
 *              S = H P H^T + R, its Cholesky factor, the NIS, the mean and the Joseph-form covariance
 *
 * The numpy code costs ~5 us a sample of the chain and ~40 us an update, nearly all of it call overhead on
 * 22 x 22 and 3 x 22 arrays. The chain's F_j P F_j^T reads F_j once into per-row lists of its nonzero entries
 * (the INS's F is the identity but for ~10 rows of a few entries): rows of F that are rows of the identity are
 * not multiplied at all, and only the upper triangle is formed and mirrored. Exact zeros contribute nothing
 * to a sum, so every entry is the dense product's with its sums taken left to right. The update's Joseph form
 * is associated as (P - K HP) - ((P - K HP) H^T) K^T + (K R) K^T, the products skipping H's zero columns.
 * BLAS and LAPACK order their sums otherwise: the last bit or two can differ from the numpy code, which stays
 * the reference (tests/filters/test_kalman_kernel.py).
 *
 * Built by setup.py (KERNELS) as fusion_plugins.filters._kalman_kernel; loaded with fusion.kernels.load.
 * Plain C API and the buffer protocol (no numpy headers): the caller allocates every output (C-contiguous
 * float64, not sharing memory with an input). Wrong dtype, shape, layout or a read-only output raise
 * TypeError or ValueError naming the argument.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

#include "../kernel_arrays.h"

/* ------------------------------------------------------------------ A P A^T by A's nonzeros */

typedef struct {            /* work space of sandwich() for n states */
    double *AP, *val;       /* (n, n) rows of A P; A's nonzero values */
    Py_ssize_t *col, *start;  /* their columns; row i's at [start[i], next start); -1: an identity row */
} Work;

static int work_alloc(Work *w, Py_ssize_t n)
{
    size_t nn = (size_t)(n * n);
    w->AP = PyMem_Malloc((2 * nn + 1) * sizeof(double));
    w->col = PyMem_Malloc((nn + (size_t)n + 2) * sizeof(Py_ssize_t));
    if (w->AP == NULL || w->col == NULL) {
        PyMem_Free(w->AP);
        PyMem_Free(w->col);
        w->AP = NULL;
        w->col = NULL;
        PyErr_NoMemory();
        return -1;
    }
    w->val = w->AP + nn;
    w->start = w->col + nn;
    return 0;
}

static void work_free(Work *w)
{
    PyMem_Free(w->AP);
    PyMem_Free(w->col);
}

/* The end of row i's nonzeros (the start of the next row that has a list). */
static inline Py_ssize_t row_end(const Py_ssize_t *start, Py_ssize_t i)
{
    Py_ssize_t e = i + 1;
    while (start[e] < 0)
        e++;
    return start[e];
}

/* y += a x (n,), unrolled by four so that gcc -O2 pairs the operations into SSE2 (the same roundings:
 * one product and one sum an entry, no fused multiply-add on x86-64's baseline) */
static inline void axpy(Py_ssize_t n, double a, const double *restrict x, double *restrict y)
{
    Py_ssize_t j = 0;
    for (; j + 4 <= n; j += 4) {
        y[j] += a * x[j];
        y[j + 1] += a * x[j + 1];
        y[j + 2] += a * x[j + 2];
        y[j + 3] += a * x[j + 3];
    }
    for (; j < n; j++)
        y[j] += a * x[j];
}

/* out[i, j] = (A P A^T)[i, j] for j >= i (the upper triangle only; the lower is not written). */
static void sandwich(const double *restrict A, const double *restrict P, Py_ssize_t n, Work *w,
                     double *restrict out)
{
    Py_ssize_t m = 0, *restrict col = w->col, *restrict start = w->start;
    double *restrict val = w->val, *restrict AP = w->AP;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *Ai = A + i * n;
        Py_ssize_t first = m;
        for (Py_ssize_t l = 0; l < n; l++) {        /* branch-free: the pattern differs from row to row */
            col[m] = l;
            val[m] = Ai[l];
            m += (Ai[l] != 0.0);
        }
        if (m - first == 1 && col[first] == i && val[first] == 1.0) {
            m = first;
            start[i] = -1;
        } else {
            start[i] = first;
        }
    }
    start[n] = m;
    /* A P: the rows of A that are not identity rows */
    for (Py_ssize_t i = 0; i < n; i++) {
        if (start[i] < 0)
            continue;
        const Py_ssize_t end = row_end(start, i);
        double *APi = AP + i * n;
        for (Py_ssize_t j = 0; j < n; j++)
            APi[j] = 0.0;
        for (Py_ssize_t e = start[i]; e < end; e++)
            axpy(n, val[e], P + col[e] * n, APi);
    }
    /* (A P) A^T, upper triangle */
    for (Py_ssize_t j = 0; j < n; j++) {
        const Py_ssize_t e0 = start[j], e1 = e0 >= 0 ? row_end(start, j) : 0;
        for (Py_ssize_t i = 0; i <= j; i++) {
            const double *APi = (start[i] < 0 ? P : AP) + i * n;    /* row i of A P */
            double b;
            if (e0 < 0) {
                b = APi[j];
            } else {
                b = 0.0;
                for (Py_ssize_t e = e0; e < e1; e++)
                    b += APi[col[e]] * val[e];
            }
            out[i * n + j] = b;
        }
    }
}

/* ------------------------------------------------------------------ propagate */

static PyObject *propagate(PyObject *self, PyObject *args)
{
    PyObject *oP, *oF, *oQ, *oout;
    if (!PyArg_ParseTuple(args, "OOOO:propagate", &oP, &oF, &oQ, &oout))
        return NULL;
    Arr A[4] = {{{0}}};
    Work w = {0};
    double *P = NULL;
    Py_ssize_t sP[2] = {-1, -1}, sF[3] = {-1, -1, -1};
    if (get_array(oP, &A[0], "P", 2, sP, 0) < 0)
        goto fail;
    const Py_ssize_t n = sP[0];
    if (sP[1] != n) {
        PyErr_Format(PyExc_ValueError, "P must be square, got (%zd, %zd)", sP[0], sP[1]);
        goto fail;
    }
    sF[1] = sF[2] = n;
    if (get_array(oF, &A[1], "F", 3, sF, 0) < 0)
        goto fail;
    const Py_ssize_t k = sF[0];
    Py_ssize_t sQ[3] = {k, n, n}, sout[2] = {n, n};
    if (get_array(oQ, &A[2], "Q", 3, sQ, 0) < 0 || get_array(oout, &A[3], "out", 2, sout, 1) < 0)
        goto fail;
    const double *P0 = DATA(A[0]), *F = DATA(A[1]), *Q = DATA(A[2]);
    double *out = DATA(A[3]);
    const size_t nn = (size_t)(n * n);
    P = PyMem_Malloc((nn + 1) * sizeof(double));
    if (P == NULL) {
        PyErr_NoMemory();
        goto fail;
    }
    if (work_alloc(&w, n) < 0)
        goto fail;
    for (Py_ssize_t i = 0; i < n; i++) {         /* the symmetric part of P */
        P[i * n + i] = P0[i * n + i];
        for (Py_ssize_t j = i + 1; j < n; j++)
            P[i * n + j] = P[j * n + i] = 0.5 * (P0[i * n + j] + P0[j * n + i]);
    }
    double *cur = P, *next = out;                  /* two buffers, swapped each sample */
    for (Py_ssize_t s = 0; s < k; s++) {
        const double *Qs = Q + s * nn;
        sandwich(F + s * nn, cur, n, &w, next);
        /* + the symmetric part of Q_s (the numpy loop's final symmetrisation, applied as the chain goes) */
        for (Py_ssize_t i = 0; i < n; i++) {
            next[i * n + i] += Qs[i * n + i];
            for (Py_ssize_t j = i + 1; j < n; j++)
                next[j * n + i] = next[i * n + j] += 0.5 * (Qs[i * n + j] + Qs[j * n + i]);
        }
        double *t = cur;
        cur = next;
        next = t;
    }
    if (cur != out)
        memcpy(out, cur, nn * sizeof(double));
    PyMem_Free(P);
    work_free(&w);
    release(A, 4);
    Py_RETURN_NONE;
fail:
    PyMem_Free(P);
    work_free(&w);
    release(A, 4);
    return NULL;
}

/* ------------------------------------------------------------------ update */

/* update(x, P, H, R, r, S, x1, P1) -> nis, or None when S is not positive definite
 *
 *   HP = H P,  S = HP H^T + R,  L L^T = S (from S's lower triangle),  w = L^-1 r,  nis = w.w,
 *   W = L^-1 HP,  x1 = x + W^T w  (x + K r),  K^T = L^-T W,
 *   P1 = (I - K H) P (I - K H)^T + K R K^T   (Joseph form), evaluated as
 *        AP = P - K HP,   P1 = AP - (AP H^T) K^T + (K R) K^T   (upper triangle, mirrored)
 *
 * x (n,), P (n, n), H (m, n), R (m, m), r (m,) the residual; outputs S (m, m), x1 (n,), P1 (n, n). The
 * mean and covariance are computed whatever the NIS (the caller's gate decides afterwards: one call
 * instead of two, and a rejection is rare). None: a pivot of the factorisation is not positive (or NaN);
 * the outputs but S are then garbage and the caller repairs S its own way (base.linearised_update_numpy).
 * The products skip the exact zeros of H (a measurement of a few states touches a few columns). */
static PyObject *update(PyObject *self, PyObject *args)
{
    PyObject *o[8];
    if (!PyArg_ParseTuple(args, "OOOOOOOO:update", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7]))
        return NULL;
    Arr A[8] = {{{0}}};
    double *mem = NULL;
    Py_ssize_t *supp = NULL;
    Py_ssize_t sx[1] = {-1}, sH[2] = {-1, -1};
    if (get_array(o[0], &A[0], "x", 1, sx, 0) < 0)
        goto fail;
    const Py_ssize_t n = sx[0];
    sH[1] = n;
    Py_ssize_t sP[2] = {n, n};
    if (get_array(o[1], &A[1], "P", 2, sP, 0) < 0 || get_array(o[2], &A[2], "H", 2, sH, 0) < 0)
        goto fail;
    const Py_ssize_t m = sH[0];
    Py_ssize_t sR[2] = {m, m}, sr[1] = {m}, sS[2] = {m, m}, sx1[1] = {n}, sP1[2] = {n, n};
    if (get_array(o[3], &A[3], "R", 2, sR, 0) < 0 || get_array(o[4], &A[4], "r", 1, sr, 0) < 0
        || get_array(o[5], &A[5], "S", 2, sS, 1) < 0 || get_array(o[6], &A[6], "x1", 1, sx1, 1) < 0
        || get_array(o[7], &A[7], "P1", 2, sP1, 1) < 0)
        goto fail;
    const double *x = DATA(A[0]), *P = DATA(A[1]), *H = DATA(A[2]), *R = DATA(A[3]), *r = DATA(A[4]);
    double *S = DATA(A[5]), *x1 = DATA(A[6]), *P1 = DATA(A[7]);
    const size_t nn = (size_t)(n * n), mn = (size_t)(m * n), mm = (size_t)(m * m);
    mem = PyMem_Malloc((nn + 6 * mn + mm + (size_t)m + 1) * sizeof(double));
    supp = PyMem_Malloc(((size_t)n + 1) * sizeof(Py_ssize_t));
    if (mem == NULL || supp == NULL) {
        PyErr_NoMemory();
        goto fail;
    }
    double *AP = mem, *HP = AP + nn, *W = HP + mn, *Kt = W + mn, *G = Kt + mn, *KtR = G + mn, *L = KtR + mn;
    double *w = L + mm;
    (void)W;

    Py_ssize_t ns = 0;                               /* the columns H touches */
    for (Py_ssize_t j = 0; j < n; j++) {
        int any = 0;
        for (Py_ssize_t a = 0; a < m; a++)
            any |= (H[a * n + j] != 0.0);
        if (any)
            supp[ns++] = j;
    }
    for (Py_ssize_t a = 0; a < m; a++) {             /* HP = H P */
        double *HPa = HP + a * n;
        const double *Ha = H + a * n;
        for (Py_ssize_t j = 0; j < n; j++)
            HPa[j] = 0.0;
        for (Py_ssize_t t = 0; t < ns; t++) {
            const double h = Ha[supp[t]];
            if (h != 0.0)
                axpy(n, h, P + supp[t] * n, HPa);
        }
    }
    for (Py_ssize_t a = 0; a < m; a++)               /* S = HP H^T + R */
        for (Py_ssize_t b = 0; b < m; b++) {
            const double *HPa = HP + a * n, *Hb = H + b * n;
            double s = 0.0;
            for (Py_ssize_t t = 0; t < ns; t++)
                if (Hb[supp[t]] != 0.0)
                    s += HPa[supp[t]] * Hb[supp[t]];
            S[a * m + b] = s + R[a * m + b];
        }
    for (Py_ssize_t j = 0; j < m; j++) {             /* L L^T = S, from S's lower triangle */
        double d = S[j * m + j];
        for (Py_ssize_t l = 0; l < j; l++)
            d -= L[j * m + l] * L[j * m + l];
        if (!(d > 0.0)) {
            PyMem_Free(mem);
            PyMem_Free(supp);
            release(A, 8);
            Py_RETURN_NONE;
        }
        d = sqrt(d);
        L[j * m + j] = d;
        for (Py_ssize_t i = j + 1; i < m; i++) {
            double s = S[i * m + j];
            for (Py_ssize_t l = 0; l < j; l++)
                s -= L[i * m + l] * L[j * m + l];
            L[i * m + j] = s / d;
        }
    }
    double nis = 0.0;
    for (Py_ssize_t a = 0; a < m; a++) {             /* w = L^-1 r */
        double s = r[a];
        for (Py_ssize_t l = 0; l < a; l++)
            s -= L[a * m + l] * w[l];
        w[a] = s / L[a * m + a];
        nis += w[a] * w[a];
    }
    for (Py_ssize_t a = 0; a < m; a++) {             /* W = L^-1 HP, row by row */
        double *Wa = W + a * n;
        memcpy(Wa, HP + a * n, (size_t)n * sizeof(double));
        for (Py_ssize_t l = 0; l < a; l++)
            axpy(n, -L[a * m + l], W + l * n, Wa);
        const double d = L[a * m + a];
        for (Py_ssize_t j = 0; j < n; j++)
            Wa[j] /= d;
    }
    for (Py_ssize_t i = 0; i < n; i++) {             /* x1 = x + w W */
        double s = 0.0;
        for (Py_ssize_t a = 0; a < m; a++)
            s += w[a] * W[a * n + i];
        x1[i] = x[i] + s;
    }
    for (Py_ssize_t a = m - 1; a >= 0; a--) {        /* L^T Kt = W, row by row from the last */
        double *Ka = Kt + a * n;
        memcpy(Ka, W + a * n, (size_t)n * sizeof(double));
        for (Py_ssize_t l = a + 1; l < m; l++)
            axpy(n, -L[l * m + a], Kt + l * n, Ka);
        const double d = L[a * m + a];
        for (Py_ssize_t j = 0; j < n; j++)
            Ka[j] /= d;
    }
    for (Py_ssize_t i = 0; i < n; i++) {             /* AP = P - K HP */
        double *APi = AP + i * n;
        memcpy(APi, P + i * n, (size_t)n * sizeof(double));
        for (Py_ssize_t a = 0; a < m; a++)
            axpy(n, -Kt[a * n + i], HP + a * n, APi);
    }
    for (Py_ssize_t i = 0; i < n; i++)               /* G = AP H^T (n, m), KtR = K R (n, m) */
        for (Py_ssize_t a = 0; a < m; a++) {
            const double *APi = AP + i * n, *Ha = H + a * n;
            double g = 0.0, kr = 0.0;
            for (Py_ssize_t t = 0; t < ns; t++)
                g += APi[supp[t]] * Ha[supp[t]];
            for (Py_ssize_t b = 0; b < m; b++)
                kr += Kt[b * n + i] * R[b * m + a];
            G[i * m + a] = g;
            KtR[i * m + a] = kr;
        }
    for (Py_ssize_t i = 0; i < n; i++)               /* P1 = AP - G K^T + (K R) K^T, mirrored */
        for (Py_ssize_t j = i; j < n; j++) {
            double g = 0.0, kr = 0.0;
            for (Py_ssize_t a = 0; a < m; a++) {
                g += G[i * m + a] * Kt[a * n + j];
                kr += KtR[i * m + a] * Kt[a * n + j];
            }
            P1[j * n + i] = P1[i * n + j] = (AP[i * n + j] - g) + kr;
        }
    PyMem_Free(mem);
    PyMem_Free(supp);
    release(A, 8);
    return PyFloat_FromDouble(nis);
fail:
    PyMem_Free(mem);
    PyMem_Free(supp);
    release(A, 8);
    return NULL;
}

static PyMethodDef methods[] = {
    {"propagate", propagate, METH_VARARGS,
     "propagate(P, F, Q, out): out = the covariance after P <- F_j P F_j^T + Q_j over F, Q (k, n, n), "
     "symmetric (F P F^T of P's symmetric part plus Q_j's symmetric part; ekf.predict_inputs)."},
    {"update", update, METH_VARARGS,
     "update(x, P, H, R, r, S, x1, P1) -> nis or None: S = H P H^T + R, nis = r^T S^-1 r, x1 = x + K r, "
     "P1 = (I - K H) P (I - K H)^T + K R K^T (symmetric); None when S is not positive definite "
     "(base.linearised_update, one iteration)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kalman_kernel",
    "Compiled covariance arithmetic of the Kalman filters (mirrors plugins/filters/ekf.py and base.py).", -1,
    methods,
};

PyMODINIT_FUNC PyInit__kalman_kernel(void)
{
    return PyModule_Create(&module);
}
