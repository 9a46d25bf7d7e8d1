/* Compiled kernel of plugins/process/ins_batch.py (fusion.kernels, setup.py KERNELS).
 *
 * integrate(x, us, dts, g, trapezoidal, out): the mean propagation of ins_batch.integrate_inputs for every
 * sigma point and IMU sample of a run, the same operations as the numpy code (paper 000 eqs. 33-52, no eta,
 * no Earth rate), written as loops: the numpy version spends its time in ~60 numpy calls per run on
 * (4, 33)-sized rows, which no library vectorises away. Results agree with it to rounding (~1e-15
 * relative): the sums over samples are accumulated in order here, the prefix products P_j formed one
 * after the other (numpy: in blocks), the time sums as numpy's pairwise sums (bit for bit).
 *
 * interval_noise(x0, x1, dts, g, qc, qnv, out): ins_batch.interval_noise for isotropic noises (Q_c diagonal),
 * the 15 x 15 products of F and the sum over the Gauss-Legendre nodes as loops (the numpy code's ~30 calls).
 *
 * imu_ok(values, max_f, max_w): whether an IMU message's values are the usual 6 finite floats within the
 * sensor's range, so that Ins.input_from can skip its Python checks (~1.2 us of ~2 us a sample).
 *
 * Plain C API and the buffer protocol (no numpy headers): the caller allocates the arrays. Every argument
 * is checked (float64, shape, C-contiguous, out writable and not overlapping the inputs); a bad one raises
 * TypeError or ValueError.
 *
 * States: x = [p(3) v(3) q(4) ba(3) bw(3)] (NED, m, m/s; q body-to-navigation, scalar first; biases in m/s^2
 * and rad/s, FRD); IMU samples u = [a(3) w(3)] (m/s^2, rad/s, FRD), sample j held over dts[j] s.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

#define NSTATE 16

/* ------------------------------------------------------------------ argument checks */

static int is_float64(const Py_buffer *v)
{
    const char *f = v->format;
    if (f == NULL || v->itemsize != 8)
        return 0;
    if (f[0] == '=' || f[0] == '@'
#if PY_LITTLE_ENDIAN
        || f[0] == '<'
#else
        || f[0] == '>' || f[0] == '!'
#endif
    )
        f++;
    return f[0] == 'd' && f[1] == '\0';
}

/* Acquire obj's buffer as a C-contiguous float64 array of ndim dimensions; shape[i] >= 0 must match (-1:
 * any). On failure: an exception set, nothing held, -1. */
static int get_array(PyObject *obj, const char *name, int ndim, const Py_ssize_t *shape, int writable, Py_buffer *v)
{
    if (!PyObject_CheckBuffer(obj)) {
        PyErr_Format(PyExc_TypeError, "%s must be a float64 array (buffer protocol), got %.100s", name,
                     Py_TYPE(obj)->tp_name);
        return -1;
    }
    if (PyObject_GetBuffer(obj, v, PyBUF_STRIDES | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0) {
        PyErr_Clear();
        PyErr_Format(PyExc_ValueError, writable ? "%s must be a writable, strided float64 array"
                                                : "%s must be a strided float64 array", name);
        return -1;
    }
    if (!is_float64(v)) {
        PyErr_Format(PyExc_TypeError, "%s must be float64, got buffer format '%s' (itemsize %zd)", name,
                     v->format ? v->format : "B", v->itemsize);
        goto fail;
    }
    if (v->ndim != ndim) {
        PyErr_Format(PyExc_ValueError, "%s must have %d dimension(s), got %d", name, ndim, v->ndim);
        goto fail;
    }
    for (int i = 0; i < ndim; i++) {
        if (shape[i] >= 0 && v->shape[i] != shape[i]) {
            PyErr_Format(PyExc_ValueError, "%s: axis %d has length %zd, expected %zd", name, i, v->shape[i], shape[i]);
            goto fail;
        }
    }
    if (!PyBuffer_IsContiguous(v, 'C')) {
        PyErr_Format(PyExc_ValueError, "%s must be C-contiguous", name);
        goto fail;
    }
    return 0;
fail:
    PyBuffer_Release(v);
    return -1;
}

static int overlaps(const Py_buffer *a, const Py_buffer *b)
{
    const char *a0 = (const char *)a->buf, *b0 = (const char *)b->buf;
    return a->len > 0 && b->len > 0 && a0 < b0 + b->len && b0 < a0 + a->len;
}

/* ------------------------------------------------------------------ numerics */

/* numpy's pairwise summation (numpy/_core/src/umath/loops_utils.h.src, PW_BLOCKSIZE 128) of n values
 * a[0], a[stride], ...: what ndarray.sum() computes, bit for bit. */
static double pairwise_sum(const double *a, Py_ssize_t n, Py_ssize_t stride)
{
    if (n < 8) {
        double res = -0.0;
        for (Py_ssize_t i = 0; i < n; i++)
            res += a[i * stride];
        return res;
    }
    if (n <= 128) {
        double r[8];
        Py_ssize_t i;
        for (int j = 0; j < 8; j++)
            r[j] = a[j * stride];
        for (i = 8; i < n - (n % 8); i += 8)
            for (int j = 0; j < 8; j++)
                r[j] += a[(i + j) * stride];
        double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++)
            res += a[i * stride];
        return res;
    }
    Py_ssize_t n2 = n / 2;
    n2 -= n2 % 8;
    return pairwise_sum(a, n2, stride) + pairwise_sum(a + n2 * stride, n - n2, stride);
}

/* ndarray.sum() of a 1-D float64 array of n values (its identity, 0, plus the pairwise sum of all). */
static double np_sum(const double *a, Py_ssize_t n, Py_ssize_t stride)
{
    return 0.0 + pairwise_sum(a, n, stride);
}

/* Hamilton product r = p (x) q (scalar first); r may be p or q. */
static inline void qmul(const double *p, const double *q, double *r)
{
    double w = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3];
    double x = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2];
    double y = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1];
    double z = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0];
    r[0] = w; r[1] = x; r[2] = y; r[3] = z;
}

/* R = |q|^2 C_b^n(q) (row-major 3 x 3; paper 000 eq. 35 for unit q), the quadratic form of
 * quaternion.ROTATION_FORM. */
static inline void rot(const double *q, double *R)
{
    double a = q[0], b = q[1], c = q[2], d = q[3];
    double aa = a * a, bb = b * b, cc = c * c, dd = d * d;
    double ab = a * b, ac = a * c, ad = a * d, bc = b * c, bd = b * d, cd = c * d;
    R[0] = aa + bb - cc - dd;
    R[1] = (bc - ad) + (bc - ad);
    R[2] = (ac + bd) + (ac + bd);
    R[3] = (ad + bc) + (ad + bc);
    R[4] = aa - bb + cc - dd;
    R[5] = (cd - ab) + (cd - ab);
    R[6] = (bd - ac) + (bd - ac);
    R[7] = (ab + cd) + (ab + cd);
    R[8] = aa - bb - cc + dd;
}

/* One state (16,) after the run: ins_batch.integrate_inputs for one sigma point. w (k, 2): the weights
 * [dt_j, dt_j r_j (+ dt_j^2 / 2)] (halved when trapezoidal), as the numpy code forms them. */
static void integrate_one(const double *x, const double *us, const double *dts, const double *w, Py_ssize_t k,
                          const double *g, double T, const double *g_p, int trap, double *out)
{
    double xs[NSTATE];
    memcpy(xs, x, sizeof xs);                  /* out may be x */
    const double *ba = xs + 10, *bw = xs + 13;
    double P[4] = {1.0, 0.0, 0.0, 0.0};        /* P_j = dq_0 (x) ... (x) dq_{j-1} */
    double Rp[9] = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0}, Rn[9];   /* C(P_j), C(P_j+1) */
    double Bv[3] = {0.0, 0.0, 0.0}, Bp[3] = {0.0, 0.0, 0.0};             /* sum b_j w_j0, sum b_j w_j1 */
    for (Py_ssize_t j = 0; j < k; j++) {
        const double *u = us + 6 * j;
        double hdt = 0.5 * dts[j];
        double h0 = (u[3] - bw[0]) * hdt, h1 = (u[4] - bw[1]) * hdt, h2 = (u[5] - bw[2]) * hdt;   /* eqs. 43-45 */
        double s = sqrt(h0 * h0 + h1 * h1 + h2 * h2);                                             /* eq. 49 */
        double s_ = s > 1e-300 ? s : 1e-300;
        double f = sin(s_) / s_;
        double dq[4] = {cos(s_), f * h0, f * h1, f * h2};   /* cos(s_) = cos(s) = 1 below 1e-300 */
        qmul(P, dq, P);
        double a0 = u[0] - ba[0], a1 = u[1] - ba[1], a2 = u[2] - ba[2];                        /* eq. 37 */
        double b[3];
        if (trap) {
            rot(P, Rn);
            for (int r = 0; r < 3; r++)
                b[r] = (Rp[3 * r] + Rn[3 * r]) * a0 + (Rp[3 * r + 1] + Rn[3 * r + 1]) * a1
                       + (Rp[3 * r + 2] + Rn[3 * r + 2]) * a2;
            memcpy(Rp, Rn, sizeof Rp);
        } else {
            for (int r = 0; r < 3; r++)
                b[r] = Rp[3 * r] * a0 + Rp[3 * r + 1] * a1 + Rp[3 * r + 2] * a2;
            rot(P, Rp);
        }
        const double w0 = w[2 * j], w1 = w[2 * j + 1];
        for (int r = 0; r < 3; r++) {
            Bv[r] += b[r] * w0;
            Bp[r] += b[r] * w1;
        }
    }
    const double *p0 = xs, *v0 = xs + 3, *q0 = xs + 6;
    double R[9];
    rot(q0, R);
    double n2 = q0[0] * q0[0] + q0[1] * q0[1] + q0[2] * q0[2] + q0[3] * q0[3];
    for (int r = 0; r < 3; r++) {
        double c0 = R[3 * r] / n2, c1 = R[3 * r + 1] / n2, c2 = R[3 * r + 2] / n2;   /* C(q_0) */
        double cbv = c0 * Bv[0] + c1 * Bv[1] + c2 * Bv[2];
        double cbp = c0 * Bp[0] + c1 * Bp[1] + c2 * Bp[2];
        out[3 + r] = v0[r] + cbv + g[r] * T;
        out[r] = p0[r] + v0[r] * T + cbp + g_p[r];
    }
    qmul(q0, P, out + 6);                      /* q_k = q_0 (x) P_k */
    memcpy(out + 10, xs + 10, 6 * sizeof(double));
}

/* ------------------------------------------------------------------ integrate */

PyDoc_STRVAR(integrate_doc,
"integrate(x, us, dts, g, trapezoidal, out) -> None\n\n"
"ins_batch.integrate_inputs into out: states x (N, 16) after the IMU samples us (k, 6), sample j held\n"
"over dts[j] s (k,), g (3,) the gravity vector g_n (m/s^2, NED); trapezoidal (bool) the integration rule.\n"
"All float64 and C-contiguous; out (N, 16) writable, may be x itself, must not overlap us, dts or g.");

static PyObject *integrate(PyObject *self, PyObject *args)
{
    PyObject *ox, *ous, *odts, *og, *otrap, *oout;
    if (!PyArg_ParseTuple(args, "OOOOOO:integrate", &ox, &ous, &odts, &og, &otrap, &oout))
        return NULL;
    int trap = PyObject_IsTrue(otrap);
    if (trap < 0)
        return NULL;
    Py_buffer bx, bus, bdts, bg, bout;
    const Py_ssize_t sx[2] = {-1, NSTATE}, sus[2] = {-1, 6}, s3[1] = {3};
    if (get_array(ox, "x", 2, sx, 0, &bx) < 0)
        return NULL;
    if (get_array(ous, "us", 2, sus, 0, &bus) < 0)
        goto r1;
    const Py_ssize_t k = bus.shape[0], N = bx.shape[0];
    const Py_ssize_t sdts[1] = {k}, sout[2] = {N, NSTATE};
    if (get_array(odts, "dts", 1, sdts, 0, &bdts) < 0)
        goto r2;
    if (get_array(og, "g", 1, s3, 0, &bg) < 0)
        goto r3;
    if (get_array(oout, "out", 2, sout, 1, &bout) < 0)
        goto r4;
    if (overlaps(&bout, &bus) || overlaps(&bout, &bdts) || overlaps(&bout, &bg)
        || (overlaps(&bout, &bx) && bout.buf != bx.buf)) {
        PyErr_SetString(PyExc_ValueError, "out must not overlap us, dts or g (and be x itself or apart from it)");
        goto r5;
    }
    double *w = PyMem_Malloc((size_t)(k > 0 ? k : 1) * 2 * sizeof(double));
    if (w == NULL) {
        PyErr_NoMemory();
        goto r5;
    }
    {
        const double *dts = (const double *)bdts.buf, *g = (const double *)bg.buf;
        /* the numpy code's weights: T = dts.sum(), r_j = T - cumsum(dts)_j, w_j1 = dt_j r_j (+ dt_j^2 / 2),
         * g_p = g sum_j w_j1; trapezoidal: b_j is twice the mean of the two ends, the weights halved */
        const double T = np_sum(dts, k, 1);
        double c = 0.0;
        for (Py_ssize_t j = 0; j < k; j++) {
            c += dts[j];
            w[2 * j] = dts[j];
            w[2 * j + 1] = dts[j] * (T - c);
            if (trap)
                w[2 * j + 1] += 0.5 * dts[j] * dts[j];
        }
        const double sw = np_sum(w + 1, k, 2);
        const double g_p[3] = {g[0] * sw, g[1] * sw, g[2] * sw};
        if (trap)
            for (Py_ssize_t j = 0; j < 2 * k; j++)
                w[j] *= 0.5;
        const double *x = (const double *)bx.buf, *us = (const double *)bus.buf;
        double *out = (double *)bout.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t n = 0; n < N; n++)
            integrate_one(x + NSTATE * n, us, dts, w, k, g, T, g_p, trap, out + NSTATE * n);
        Py_END_ALLOW_THREADS
    }
    PyMem_Free(w);
    PyBuffer_Release(&bout);
    PyBuffer_Release(&bg);
    PyBuffer_Release(&bdts);
    PyBuffer_Release(&bus);
    PyBuffer_Release(&bx);
    Py_RETURN_NONE;
r5:
    PyBuffer_Release(&bout);
r4:
    PyBuffer_Release(&bg);
r3:
    PyBuffer_Release(&bdts);
r2:
    PyBuffer_Release(&bus);
r1:
    PyBuffer_Release(&bx);
    return NULL;
}

/* ------------------------------------------------------------------ interval_noise */

#define NE 15     /* error state [dp dv dth dba dbw] */

/* ins_batch._GL_POWERS and _GL_WEIGHTS (4-point Gauss-Legendre on [0, 1]: [s, s^2 / 2, s^3 / 6] at the
 * nodes, and the weights), to the last bit (repr) */
static const double GL_POWERS[4][3] = {
    {0.06943184420297371, 0.002410390494713007, 5.578595243241409e-05},
    {0.33000947820757187, 0.054453127853416924, 0.005990016103225439},
    {0.6699905217924281, 0.22444364964584507, 0.05012503931307222},
    {0.9305681557970262, 0.43297854629173926, 0.13430534910746036},
};
static const double GL_WEIGHTS[4] = {0.17392742256872679, 0.3260725774312732, 0.3260725774312732, 0.17392742256872679};

static void matmul15(const double A[NE][NE], const double B[NE][NE], double C[NE][NE])
{
    for (int i = 0; i < NE; i++)
        for (int j = 0; j < NE; j++) {
            double s = 0.0;
            for (int l = 0; l < NE; l++)
                s += A[i][l] * B[l][j];
            C[i][j] = s;
        }
}

/* ins_batch.interval_noise for isotropic white noises (qc, the diagonal of Q_c, given): Qm (16, 16) =
 * sum_m w_m G Phi_m Q_c Phi_m^T G^T (+ the quaternion-norm term), the numpy code's operations. */
static void interval_noise_iso(const double *x0, const double *x1, const double *dts, Py_ssize_t k, const double *g,
                               const double *qc, double qnv, double *Qm)
{
    const double T = np_sum(dts, k, 1);
    double fn[3], qm[4], R[9];
    for (int i = 0; i < 3; i++)
        fn[i] = (x1[3 + i] - x0[3 + i]) / T - g[i];
    for (int i = 0; i < 4; i++)
        qm[i] = x0[6 + i] + x1[6 + i];
    rot(qm, R);
    const double n2 = qm[0] * qm[0] + qm[1] * qm[1] + qm[2] * qm[2] + qm[3] * qm[3];
    static const double zero[NE][NE];
    double F[NE][NE], F2[NE][NE], F3[NE][NE];
    memcpy(F, zero, sizeof F);
    for (int i = 0; i < 3; i++) {
        F[i][3 + i] = 1.0;
        for (int j = 0; j < 3; j++)
            F[3 + i][9 + j] = F[6 + i][12 + j] = -(R[3 * i + j] / n2);   /* -C_b^n at mid-interval */
    }
    F[3][7] = fn[2]; F[3][8] = -fn[1];                                   /* -[f_n x] */
    F[4][6] = -fn[2]; F[4][8] = fn[0];
    F[5][6] = fn[1]; F[5][7] = -fn[0];
    matmul15(F, F, F2);
    matmul15(F2, F, F3);
    const double Tp[3] = {T, T * T, T * T * T};
    const double *q = x1 + 6;
    const double Xi[4][3] = {{-0.5 * q[1], -0.5 * q[2], -0.5 * q[3]}, {0.5 * q[0], 0.5 * q[3], -0.5 * q[2]},
                             {-0.5 * q[3], 0.5 * q[0], 0.5 * q[1]}, {0.5 * q[2], -0.5 * q[1], 0.5 * q[0]}};
    double A[NSTATE][4 * NE];                  /* A = [G Phi_m sqrt(w_m Q_c)]_m, Qm = A A^T */
    for (int m = 0; m < 4; m++) {
        const double c0 = GL_POWERS[m][0] * Tp[0], c1 = GL_POWERS[m][1] * Tp[1], c2 = GL_POWERS[m][2] * Tp[2];
        const double wm = GL_WEIGHTS[m] * T;
        double Phi[NE][NE];
        for (int i = 0; i < NE; i++)
            for (int j = 0; j < NE; j++)
                Phi[i][j] = c0 * F[i][j] + c1 * F2[i][j] + c2 * F3[i][j] + (i == j ? 1.0 : 0.0);
        for (int j = 0; j < NE; j++) {
            const double sc = sqrt(wm * qc[j]);
            double *col = &A[0][m * NE + j];
            for (int i = 0; i < 6; i++)                                  /* dp, dv */
                col[i * 4 * NE] = Phi[i][j] * sc;
            for (int i = 0; i < 4; i++)                                  /* q = [0, dth] (x) q1 / 2 */
                col[(6 + i) * 4 * NE] = (Xi[i][0] * Phi[6][j] + Xi[i][1] * Phi[7][j] + Xi[i][2] * Phi[8][j]) * sc;
            for (int i = 0; i < 6; i++)                                  /* dba, dbw */
                col[(10 + i) * 4 * NE] = Phi[9 + i][j] * sc;
        }
    }
    for (int i = 0; i < NSTATE; i++)
        for (int j = 0; j <= i; j++) {
            double s = 0.0;
            for (int l = 0; l < 4 * NE; l++)
                s += A[i][l] * A[j][l];
            Qm[NSTATE * i + j] = Qm[NSTATE * j + i] = s;
        }
    if (qnv != 0.0) {
        const double c = qnv * (double)k / (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        for (int i = 0; i < 4; i++)
            for (int j = 0; j < 4; j++)
                Qm[NSTATE * (6 + i) + 6 + j] += q[i] * q[j] * c;
    }
}

PyDoc_STRVAR(interval_noise_doc,
"interval_noise(x0, x1, dts, g, qc, qnv, out) -> None\n\n"
"ins_batch.interval_noise into out (16, 16) for isotropic noises: the means x0, x1 (16,) before and after\n"
"the run, dts (k,) s (k >= 1, sum > 0), g (3,) g_n (m/s^2), qc (15,) the diagonal of Q_c (0, N_a^2, N_w^2,\n"
"N_ba^2, N_bw^2 per axis), qnv (float) the quaternion-norm variance per sample. All float64, C-contiguous;\n"
"out writable, apart from the inputs.");

static PyObject *interval_noise(PyObject *self, PyObject *args)
{
    PyObject *ox0, *ox1, *odts, *og, *oqc, *oout;
    double qnv;
    if (!PyArg_ParseTuple(args, "OOOOOdO:interval_noise", &ox0, &ox1, &odts, &og, &oqc, &qnv, &oout))
        return NULL;
    Py_buffer b[6];
    PyObject *objs[6] = {ox0, ox1, odts, og, oqc, oout};
    const char *names[6] = {"x0", "x1", "dts", "g", "qc", "out"};
    const Py_ssize_t shapes[6][2] = {{NSTATE}, {NSTATE}, {-1}, {3}, {NE}, {NSTATE, NSTATE}};
    int got = 0;
    for (; got < 6; got++)
        if (get_array(objs[got], names[got], got == 5 ? 2 : 1, shapes[got], got == 5, &b[got]) < 0)
            goto done;
    const Py_ssize_t k = b[2].shape[0];
    for (int i = 0; i < 5; i++)
        if (overlaps(&b[5], &b[i])) {
            PyErr_Format(PyExc_ValueError, "out must not overlap %s", names[i]);
            goto done;
        }
    const double *dts = (const double *)b[2].buf;
    const double T = np_sum(dts, k, 1);
    if (k < 1 || !(T > 0.0) || !isfinite(T)) {
        PyErr_SetString(PyExc_ValueError, "dts must hold at least one sample and sum to a finite T > 0");
        goto done;
    }
    interval_noise_iso((const double *)b[0].buf, (const double *)b[1].buf, dts, k, (const double *)b[3].buf,
                       (const double *)b[4].buf, qnv, (double *)b[5].buf);
done:
    for (int i = 0; i < got; i++)
        PyBuffer_Release(&b[i]);
    if (PyErr_Occurred())
        return NULL;
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ imu_ok */

PyDoc_STRVAR(imu_ok_doc,
"imu_ok(values, max_f, max_w) -> bool\n\n"
"True when values is a tuple of exactly 6 floats [ax ay az gx gy gz], all finite, |a| <= max_f and\n"
"|w| <= max_w (floats, inf for no limit): the common case of Ins.input_from in one call. False for anything\n"
"else, which the Python code then refuses with its own messages (or converts: ints, numpy scalars).");

static PyObject *imu_ok(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3) {
        PyErr_Format(PyExc_TypeError, "imu_ok expects 3 arguments, got %zd", nargs);
        return NULL;
    }
    const double lim_f = PyFloat_AsDouble(args[1]), lim_w = PyFloat_AsDouble(args[2]);
    if ((lim_f == -1.0 || lim_w == -1.0) && PyErr_Occurred())
        return NULL;
    PyObject *vals = args[0];
    if (!PyTuple_CheckExact(vals) || PyTuple_GET_SIZE(vals) != 6)
        Py_RETURN_FALSE;
    for (int i = 0; i < 6; i++) {
        PyObject *item = PyTuple_GET_ITEM(vals, i);
        if (!PyFloat_CheckExact(item))
            Py_RETURN_FALSE;
        const double v = fabs(PyFloat_AS_DOUBLE(item));
        if (!(v <= (i < 3 ? lim_f : lim_w)) || !isfinite(v))    /* nan fails the comparison */
            Py_RETURN_FALSE;
    }
    Py_RETURN_TRUE;
}

static PyMethodDef methods[] = {
    {"imu_ok", (PyCFunction)(void (*)(void))imu_ok, METH_FASTCALL, imu_ok_doc},
    {"integrate", integrate, METH_VARARGS, integrate_doc},
    {"interval_noise", interval_noise, METH_VARARGS, interval_noise_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_ins_batch_kernel",
    "Compiled kernels of fusion_plugins.process.ins_batch (see the C source's header).", -1, methods,
};

PyMODINIT_FUNC PyInit__ins_batch_kernel(void)
{
    return PyModule_Create(&module);
}
