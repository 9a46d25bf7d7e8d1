/* The EKF's covariance chain over a run of input samples, compiled (ekf.ExtendedKalmanFilter.predict_inputs):
 *
 *     P <- F_j P F_j^T + Q_j,   j = 0 .. k-1,   then symmetrised
 *
 * The numpy loop costs two 22 x 22 products and an addition a sample, ~5 us of which most is call overhead.
 * Here each F_j is read once into per-row lists of its nonzero entries (the INS's F is the identity but for
 * ~10 rows of a few entries each), rows of F that are rows of the identity are not multiplied at all, and only
 * the upper triangle of F P F^T is formed and mirrored. Exact zeros of F contribute nothing to a sum, so the
 * result is that of the dense product with its sums taken left to right (BLAS may order them otherwise: the
 * last bit or two can differ from the numpy loop).
 *
 * Built by setup.py (KERNELS) as fusion_plugins.filters._ekf_kernel; loaded with fusion.kernels.load.
 * Plain C API and the buffer protocol (no numpy headers): the caller allocates the output.
 *
 *   propagate(P, F, Q, out) -> None
 *       P (n, n), F (k, n, n), Q (k, n, n), out (n, n): C-contiguous float64, k >= 0. out receives the
 *       covariance after the run, symmetric: F P F^T of the symmetric part of P, plus the symmetric part of
 *       each Q_j (the numpy loop's final symmetrisation, applied as the chain goes: the map is linear).
 *       Wrong dtype, shape, layout or a read-only out raise TypeError or ValueError naming the argument.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>

typedef struct {
    Py_buffer view;
    int held;
} Arr;

static void release(Arr *a, int count)
{
    for (int i = 0; i < count; i++) {
        if (a[i].held) {
            PyBuffer_Release(&a[i].view);
            a[i].held = 0;
        }
    }
}

/* A C-contiguous float64 buffer of ndim dimensions; shape[d] < 0 accepts any length (set to the array's).
 * Returns 0, or -1 with TypeError / ValueError set. */
static int get_array(PyObject *obj, Arr *a, const char *name, int ndim, Py_ssize_t *shape, int writable)
{
    if (PyObject_GetBuffer(obj, &a->view, PyBUF_RECORDS_RO) != 0) {
        PyErr_Clear();
        PyErr_Format(PyExc_TypeError, "%s must be a float64 array (buffer protocol), got %.100s",
                     name, Py_TYPE(obj)->tp_name);
        return -1;
    }
    a->held = 1;
    const char *f = a->view.format ? a->view.format : "B";
    if (f[0] == '@' || f[0] == '=' || f[0] == '<')
        f++;
    if (strcmp(f, "d") != 0 || a->view.itemsize != 8) {
        PyErr_Format(PyExc_TypeError, "%s must be a float64 array, got format '%s'", name,
                     a->view.format ? a->view.format : "B");
        return -1;
    }
    if (a->view.ndim != ndim) {
        PyErr_Format(PyExc_ValueError, "%s must have %d dimension(s), got %d", name, ndim, a->view.ndim);
        return -1;
    }
    for (int d = 0; d < ndim; d++) {
        if (shape[d] < 0) {
            shape[d] = a->view.shape[d];
        } else if (a->view.shape[d] != shape[d]) {
            PyErr_Format(PyExc_ValueError, "%s has length %zd along axis %d, expected %zd", name,
                         a->view.shape[d], d, shape[d]);
            return -1;
        }
    }
    if (!PyBuffer_IsContiguous(&a->view, 'C')) {
        PyErr_Format(PyExc_ValueError, "%s must be C-contiguous", name);
        return -1;
    }
    if (writable && a->view.readonly) {
        PyErr_Format(PyExc_ValueError, "%s is read-only (an output array)", name);
        return -1;
    }
    return 0;
}

#define DATA(a) ((double *)(a).view.buf)

static PyObject *propagate(PyObject *self, PyObject *args)
{
    PyObject *oP, *oF, *oQ, *oout;
    if (!PyArg_ParseTuple(args, "OOOO:propagate", &oP, &oF, &oQ, &oout))
        return NULL;
    Arr A[4] = {{{0}}};
    Py_ssize_t sP[2] = {-1, -1}, sF[3] = {-1, -1, -1};
    double *mem = NULL;
    Py_ssize_t *idx = NULL;
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

    /* work: the current P, F P (non-identity rows), the nonzeros of F_j by row */
    mem = PyMem_Malloc((3 * nn + 1) * sizeof(double));
    idx = PyMem_Malloc((nn + (size_t)n + 1) * sizeof(Py_ssize_t));
    if (mem == NULL || idx == NULL) {
        PyErr_NoMemory();
        goto fail;
    }
    double *P = mem, *FP = mem + nn, *val = mem + 2 * nn;
    Py_ssize_t *col = idx, *start = idx + nn;   /* row i's nonzeros: col/val[start[i] .. start[i+1]) */

    for (Py_ssize_t i = 0; i < n; i++) {         /* the symmetric part of P */
        P[i * n + i] = P0[i * n + i];
        for (Py_ssize_t j = i + 1; j < n; j++)
            P[i * n + j] = P[j * n + i] = 0.5 * (P0[i * n + j] + P0[j * n + i]);
    }
    for (Py_ssize_t s = 0; s < k; s++) {
        const double *Fs = F + s * nn, *Qs = Q + s * nn;
        /* nonzeros of F_s by row; an identity row (one 1 on the diagonal) is marked by start[i] = -1 */
        Py_ssize_t m = 0;
        for (Py_ssize_t i = 0; i < n; i++) {
            const double *Fi = Fs + i * n;
            Py_ssize_t first = m;
            for (Py_ssize_t l = 0; l < n; l++) {
                if (Fi[l] != 0.0) {
                    col[m] = l;
                    val[m] = Fi[l];
                    m++;
                }
            }
            if (m - first == 1 && col[first] == i && val[first] == 1.0) {
                m = first;
                start[i] = -1;
            } else {
                start[i] = first;
            }
        }
        start[n] = m;
        /* F P: the rows of F that are not identity rows */
        for (Py_ssize_t i = 0; i < n; i++) {
            if (start[i] < 0)
                continue;
            Py_ssize_t end = i + 1;
            while (start[end] < 0)
                end++;
            end = start[end];
            double *FPi = FP + i * n;
            for (Py_ssize_t j = 0; j < n; j++)
                FPi[j] = 0.0;
            for (Py_ssize_t e = start[i]; e < end; e++) {
                const double f = val[e], *Pl = P + col[e] * n;
                for (Py_ssize_t j = 0; j < n; j++)
                    FPi[j] += f * Pl[j];
            }
        }
        /* (F P) F^T, upper triangle, + the symmetric part of Q_s; mirrored into out */
        for (Py_ssize_t j = 0; j < n; j++) {
            Py_ssize_t e0 = start[j], e1 = 0;
            if (e0 >= 0) {
                Py_ssize_t nx = j + 1;
                while (start[nx] < 0)
                    nx++;
                e1 = start[nx];
            }
            for (Py_ssize_t i = 0; i <= j; i++) {
                const double *Ai = (start[i] < 0 ? P : FP) + i * n;    /* row i of F P */
                double b;
                if (e0 < 0) {
                    b = Ai[j];
                } else {
                    b = 0.0;
                    for (Py_ssize_t e = e0; e < e1; e++)
                        b += Ai[col[e]] * val[e];
                }
                out[i * n + j] = b + (i == j ? Qs[i * n + i] : 0.5 * (Qs[i * n + j] + Qs[j * n + i]));
            }
        }
        for (Py_ssize_t i = 0; i < n; i++)
            for (Py_ssize_t j = i; j < n; j++)
                P[i * n + j] = P[j * n + i] = out[i * n + j];
    }
    memcpy(out, P, nn * sizeof(double));
    PyMem_Free(mem);
    PyMem_Free(idx);
    release(A, 4);
    Py_RETURN_NONE;
fail:
    PyMem_Free(mem);
    PyMem_Free(idx);
    release(A, 4);
    return NULL;
}

static PyMethodDef methods[] = {
    {"propagate", propagate, METH_VARARGS,
     "propagate(P, F, Q, out): out = the covariance after P <- F_j P F_j^T + Q_j over the run (k, n, n), "
     "symmetrised (plugins/filters/ekf.py predict_inputs)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_ekf_kernel", "Compiled covariance chain of the EKF's run of input samples.", -1,
    methods,
};

PyMODINIT_FUNC PyInit__ekf_kernel(void)
{
    return PyModule_Create(&module);
}
