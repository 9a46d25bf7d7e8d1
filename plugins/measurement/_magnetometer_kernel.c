/* The magnetometer's h and Jacobian for one state, compiled (plugins/measurement/magnetometer.py):
 *
 *   h = C_n^b(q) m_n = R(q*) m_n / |q|^2,    R the homogeneous rotation form (paper 000 eq. 35)
 *   dh/dq = (d(R(q*) m)/dq* - 2 (C m) q*^T) / |q|^2  diag(1, -1, -1, -1)
 *
 * The numpy code (the reference, and what runs without this module) costs ~8 us for h and ~12 us for the
 * Jacobian, call overhead on (4,) and (3, 3) arrays; here ~0.5 us each. The same formulas; the sums numpy
 * hands to BLAS or einsum (q q^T against the rotation form) are written out, so the last bit may differ.
 *
 * Built by setup.py (KERNELS) as fusion_plugins.measurement._magnetometer_kernel; loaded with
 * fusion.kernels.load. Plain C API and the buffer protocol (no numpy headers):
 *
 *   h(x, start, m_n, out) -> None          x (n,), q = x[start:start+4]; m_n (3,); out (3,)
 *   jacobian(x, start, m_n, out) -> None   out (3, n): zero but for the q columns
 *
 * C-contiguous float64 arrays; wrong dtype, shape, layout, a read-only out or a q block outside x raise
 * TypeError or ValueError naming the argument.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>

#include "../kernel_arrays.h"

/* Parse (x, start, m_n, out) with out of shape (3,) (jac = 0) or (3, n) (jac = 1); fills q* (the conjugate). */
static int parse(PyObject *args, const char *fmt, Arr *A, int jac, double qc[4], Py_ssize_t *n_out)
{
    PyObject *ox, *om, *oout;
    Py_ssize_t start;
    if (!PyArg_ParseTuple(args, fmt, &ox, &start, &om, &oout))
        return -1;
    Py_ssize_t sx[1] = {-1}, sm[1] = {3};
    if (get_array(ox, &A[0], "x", 1, sx, 0) < 0 || get_array(om, &A[1], "m_n", 1, sm, 0) < 0)
        return -1;
    const Py_ssize_t n = sx[0];
    if (start < 0 || start + 4 > n) {
        PyErr_Format(PyExc_ValueError, "the q block x[%zd:%zd] is outside x (%zd states)", start, start + 4, n);
        return -1;
    }
    Py_ssize_t sh[1] = {3}, sH[2] = {3, n};
    if ((jac ? get_array(oout, &A[2], "out", 2, sH, 1) : get_array(oout, &A[2], "out", 1, sh, 1)) < 0)
        return -1;
    const double *q = DATA(A[0]) + start;
    qc[0] = q[0];
    qc[1] = -q[1];
    qc[2] = -q[2];
    qc[3] = -q[3];
    *n_out = n;
    return start;
}

/* R(q) m / |q|^2 for the homogeneous form R (q not necessarily unit) */
static void rotate(const double q[4], const double *m, double n2, double out[3])
{
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    const double C[3][3] = {
        {(w * w + x * x - y * y - z * z) / n2, 2.0 * (x * y - w * z) / n2, 2.0 * (x * z + w * y) / n2},
        {2.0 * (x * y + w * z) / n2, (w * w - x * x + y * y - z * z) / n2, 2.0 * (y * z - w * x) / n2},
        {2.0 * (x * z - w * y) / n2, 2.0 * (y * z + w * x) / n2, (w * w - x * x - y * y + z * z) / n2}};
    for (int r = 0; r < 3; r++)
        out[r] = C[r][0] * m[0] + C[r][1] * m[1] + C[r][2] * m[2];
}

static PyObject *mag_h(PyObject *self, PyObject *args)
{
    Arr A[3] = {{{0}}};
    double q[4];
    Py_ssize_t n;
    if (parse(args, "OnOO:h", A, 0, q, &n) < 0) {
        release(A, 3);
        return NULL;
    }
    const double n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    rotate(q, DATA(A[1]), n2, DATA(A[2]));
    release(A, 3);
    Py_RETURN_NONE;
}

static PyObject *mag_jacobian(PyObject *self, PyObject *args)
{
    Arr A[3] = {{{0}}};
    double q[4];
    Py_ssize_t n;
    const Py_ssize_t start = parse(args, "OnOO:jacobian", A, 1, q, &n);
    if (start < 0) {
        release(A, 3);
        return NULL;
    }
    const double *m = DATA(A[1]);
    double *H = DATA(A[2]);
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    const double n2 = w * w + x * x + y * y + z * z;
    /* d(R(q) m)/dq_k (homogeneous R), column k of Rv */
    const double M[4][3][3] = {
        {{w, -z, y}, {z, w, -x}, {-y, x, w}},
        {{x, y, z}, {y, -x, -w}, {z, w, -x}},
        {{-y, x, w}, {x, y, z}, {-w, z, -y}},
        {{-z, -w, x}, {w, -z, y}, {x, y, z}}};
    double Rv[3][4];
    for (int k = 0; k < 4; k++)
        for (int r = 0; r < 3; r++)
            Rv[r][k] = (M[k][r][0] * m[0] + M[k][r][1] * m[1] + M[k][r][2] * m[2]) * 2.0;
    static const double flip[4] = {1.0, -1.0, -1.0, -1.0};
    memset(H, 0, (size_t)(3 * n) * sizeof(double));
    for (int r = 0; r < 3; r++) {
        const double Cv = (Rv[r][0] * q[0] + Rv[r][1] * q[1] + Rv[r][2] * q[2] + Rv[r][3] * q[3]) / (2.0 * n2);
        for (int k = 0; k < 4; k++)
            H[r * n + start + k] = (Rv[r][k] - 2.0 * Cv * q[k]) / n2 * flip[k];
    }
    release(A, 3);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"h", mag_h, METH_VARARGS,
     "h(x, start, m_n, out): out (3,) = C_n^b(q) m_n, q = x[start:start+4] (magnetometer.h for one state)."},
    {"jacobian", mag_jacobian, METH_VARARGS,
     "jacobian(x, start, m_n, out): out (3, n) = dh/dx, zero but for the q columns (magnetometer.jacobian)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_magnetometer_kernel",
    "Compiled h and Jacobian of the magnetometer for one state (mirrors plugins/measurement/magnetometer.py).",
    -1, methods,
};

PyMODINIT_FUNC PyInit__magnetometer_kernel(void)
{
    return PyModule_Create(&module);
}
