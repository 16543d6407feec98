/* posecast native SSI kernels: the implementation, compiled once per ISA level.
 *
 * The including file sets the target (a GCC pragma) and defines
 *   PC_VW      floats per vector (16 AVX-512, 8 AVX2, 4 portable)
 *   PC_MR      rows per register block, PC_NB vectors per register block
 *   PC_NAME    the level's name, PC_TABLE the PcKernels symbol to define
 *   PC_BF16    1: the bf16 gates on the AVX-512-BF16 instructions; 0: the same
 *              arithmetic in plain vector code (precision bf16 on any other level)
 *   PC_SPLAT   broadcast of one float to a vector
 *   PC_RCP     (optional) the level's reciprocal estimate
 * and then includes this file. Vectors are GCC vector extensions, so one source
 * serves every width; the compiler emits the level's instructions for them.
 *
 * Numerics follow the numpy reference (body/batch_fk.py, body/ik.py,
 * online/inference/anomaly.py and the ONNX decoder graph) operation by operation;
 * tests/online/inference/test_native.py checks every level this CPU runs against a
 * float64 reference.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "pc_geom.h"
#include "pc_kernels.h"

typedef float vf __attribute__((vector_size(PC_VW * 4)));
typedef int32_t vi __attribute__((vector_size(PC_VW * 4)));
typedef float vfu __attribute__((vector_size(PC_VW * 4), aligned(4)));

#define LOADA(p) (*(const vf *)(p))
#define STOREA(p, v) (*(vf *)(p) = (v))
#define LOADU(p) ((vf)(*(const vfu *)(p)))
#define STOREU(p, v) (*(vfu *)(p) = (vfu)(v))

/* PC_SPLAT (from the level's file) broadcasts one float: GCC turns neither 0 + x
 * nor a lane loop into a single broadcast on vector-extension types. */
static inline vf splat(float x) { return (vf)PC_SPLAT(x); }
static inline vf vsel(vi m, vf a, vf b) { return (vf)((m & (vi)a) | (~m & (vi)b)); }
static inline vf vmax(vf a, vf b) { return vsel(a > b, a, b); }
static inline vf vmin(vf a, vf b) { return vsel(a < b, a, b); }

/* exp for the gates: Cody-Waite range reduction, degree-6 minimax polynomial
 * (relative error about 2e-7 over the clamped range). */
static inline vf vexp(vf x) {
    x = vmin(vmax(x, splat(-87.0f)), splat(88.0f));
    const vf magic = splat(12582912.0f); /* 1.5 * 2^23: round to nearest */
    vf t = x * splat(1.44269504088896341f);
    vf n = (t + magic) - magic;
    vf r = x - n * splat(0.693359375f);
    r = r - n * splat(-2.12194440e-4f);
    vf p = splat(1.9875691500e-4f);
    p = p * r + splat(1.3981999507e-3f);
    p = p * r + splat(8.3334519073e-3f);
    p = p * r + splat(4.1665795894e-2f);
    p = p * r + splat(1.6666665459e-1f);
    p = p * r + splat(5.0000001201e-1f);
    p = p * r * r + r + splat(1.0f);
    vi e = (__builtin_convertvector(n, vi) + 127) << 23;
    return p * (vf)e;
}
/* 1 / x: the level's reciprocal estimate (PC_RCP, about 12 bits) and one Newton
 * step (about 22 bits); the division it replaces was a fifth of the decoder step. */
static inline vf vrcp(vf x) {
#ifdef PC_RCP
    vf r = (vf)PC_RCP(x);
    return r * (splat(2.0f) - x * r);
#else
    return splat(1.0f) / x;
#endif
}
static inline vf vsigmoid(vf x) { return vrcp(splat(1.0f) + vexp(-x)); }
static inline vf vtanh(vf x) {
    /* tanh x = sign(x) (1 - e) / (1 + e), e = exp(-2|x|): no cancellation near 0
     * beyond that of 1 - e, which the reference's own tanh shares in float32. */
    vf ax = vmax(x, -x);
    vf e = vexp(splat(-2.0f) * ax);
    vf y = (splat(1.0f) - e) * vrcp(splat(1.0f) + e);
    return vsel(x < splat(0.0f), -y, y);
}

/* --- the products: one register-blocked block, two kinds of k step ---------------- */

/* The k step of a block, fp32: acc (PC_MR rows x PC_NB vectors) += A's column k over
 * the block's rows (a, stride lda) times W's row k over the block's columns (w). */
static inline __attribute__((always_inline)) void madd_f32(vf acc[PC_MR][PC_NB], const float *a, int lda,
                                                            const float *w) {
    vf b[PC_NB];
    for (int j = 0; j < PC_NB; j++) b[j] = LOADA(w + j * PC_VW);
    for (int i = 0; i < PC_MR; i++) {
        vf s = splat(a[(size_t)i * lda]);
        for (int j = 0; j < PC_NB; j++) acc[i][j] += s * b[j];
    }
}

#if PC_BF16
#include <immintrin.h>
#if PC_VW != 16
#error "the bf16 instructions take 16-float vectors"
#endif
/* The k step with bf16 inputs: a and w hold pairs (k even low, k odd high), summed
 * into fp32 by vdpbf16ps. */
static inline __attribute__((always_inline)) void madd_bf16(vf acc[PC_MR][PC_NB], const uint32_t *a, int lda,
                                                             const uint32_t *w) {
    __m512bh b[PC_NB];
    for (int j = 0; j < PC_NB; j++) b[j] = (__m512bh)_mm512_load_si512((const void *)(w + j * PC_VW));
    for (int i = 0; i < PC_MR; i++) {
        __m512bh s = (__m512bh)_mm512_set1_epi32((int)a[(size_t)i * lda]);
        for (int j = 0; j < PC_NB; j++) acc[i][j] = (vf)_mm512_dpbf16_ps((__m512)acc[i][j], s, b[j]);
    }
}

/* float32 rows (R x K) -> bf16 pairs (R x K/2), round to nearest even. */
static void to_bf16(const float *A, int R, int K, uint32_t *out) {
    for (int r = 0; r < R; r++)
        for (int k = 0; k < K; k += 32) {
            __m512 lo = _mm512_loadu_ps(A + (size_t)r * K + k);
            __m512 hi = _mm512_loadu_ps(A + (size_t)r * K + k + 16);
            __m512bh v = _mm512_cvtne2ps_pbh(hi, lo);
            _mm512_storeu_si512((void *)(out + ((size_t)r * K + k) / 2), (__m512i)v);
        }
}
#else
/* The bf16 arithmetic on a level without the instructions (precision bf16 on a CPU
 * without avx512_bf16): the same pairs, the same order of accumulation as the
 * instruction's definition (Intel SDM, VDPBF16PS: per lane, acc += odd product, then
 * acc += even product, each rounded to nearest even). A bf16 product is exact in fp32
 * (8 x 8 significant bits), so a multiply and an add, fused or not, round as the
 * instruction's FMA does. What it does not copy: the instruction's flush of a
 * denormal sum to zero (a gate input under 1.2e-38). */
typedef uint32_t vu __attribute__((vector_size(PC_VW * 4)));

static inline float bf16_hi(uint32_t pair) {
    float f;
    pair &= 0xffff0000u;
    memcpy(&f, &pair, 4);
    return f;
}
static inline float bf16_lo(uint32_t pair) { return bf16_hi(pair << 16); }

static inline __attribute__((always_inline)) void madd_bf16(vf acc[PC_MR][PC_NB], const uint32_t *a, int lda,
                                                             const uint32_t *w) {
    vf lo[PC_NB], hi[PC_NB];
    for (int j = 0; j < PC_NB; j++) {
        vu p = *(const vu *)(w + j * PC_VW);
        lo[j] = (vf)(p << 16);
        hi[j] = (vf)(p & 0xffff0000u);
    }
    for (int i = 0; i < PC_MR; i++) {
        const uint32_t ap = a[(size_t)i * lda];
        vf ahi = splat(bf16_hi(ap)), alo = splat(bf16_lo(ap));
        for (int j = 0; j < PC_NB; j++) {
            acc[i][j] += ahi * hi[j];
            acc[i][j] += alo * lo[j];
        }
    }
}

/* float32 rows (R x K) -> bf16 pairs (R x K/2) as vcvtne2ps2bf16 makes them. */
static void to_bf16(const float *A, int R, int K, uint32_t *out) {
    for (size_t i = 0; i < (size_t)R * K; i += 2)
        out[i / 2] = pc_bf16_bits(A[i]) | pc_bf16_bits(A[i + 1]) << 16;
}
#endif

/* One block of C = A W + bias: rows r0 .. r0 + PC_MR, PC_NB vectors of columns from
 * c0, its accumulators in registers over all K. A (lda) and W (N per row) hold 32-bit
 * items: floats (bf16 = 0), or bf16 pairs (bf16 = 1: K and lda count pairs, W packed
 * by pack_pairs); bias and C (ldc) are floats. Inlined with bf16 a constant, so each
 * product is its own loop nest with no test of the kind left in it. */
static inline __attribute__((always_inline)) void gemm_block(int bf16, const void *A, int lda, int K,
                                                              const void *W, int N, const float *bias, float *C,
                                                              int ldc, int r0, int c0) {
    vf acc[PC_MR][PC_NB];
    for (int j = 0; j < PC_NB; j++) {
        vf b = LOADA(bias + c0 + j * PC_VW);
        for (int i = 0; i < PC_MR; i++) acc[i][j] = b;
    }
    for (int k = 0; k < K; k++) {
        if (bf16)
            madd_bf16(acc, (const uint32_t *)A + (size_t)r0 * lda + k, lda,
                      (const uint32_t *)W + (size_t)k * N + c0);
        else
            madd_f32(acc, (const float *)A + (size_t)r0 * lda + k, lda, (const float *)W + (size_t)k * N + c0);
    }
    for (int i = 0; i < PC_MR; i++)
        for (int j = 0; j < PC_NB; j++) STOREA(C + (size_t)(r0 + i) * ldc + c0 + j * PC_VW, acc[i][j]);
}

/* C (R x N, ldc) = A (R x K, lda) W (K x N) + bias in fp32 (the GRU gates in fp32, the
 * heads, the anomaly AE); R a multiple of PC_MR, N of PC_NB * PC_VW; W, bias and C
 * 64-byte aligned with N, ldc multiples of PC_VW. Row block by row block: against
 * panel by panel (gemm_bf16's order), the decoder step 5 % faster on the generic
 * level, within 1.5 % on AVX2 (2026-12-07). */
static void gemm(const float *A, int lda, int R, int K, const float *W, int N, const float *bias, float *C,
                 int ldc) {
    for (int r0 = 0; r0 < R; r0 += PC_MR)
        for (int c0 = 0; c0 < N; c0 += PC_NB * PC_VW) gemm_block(0, A, lda, K, W, N, bias, C, ldc, r0, c0);
}

/* The same product with the GRU gates' inputs in bf16: A as (R x K2) pairs, W as
 * (K2 x N) pairs, fp32 sums (the level's instructions, or their arithmetic in plain
 * vector code). Column panel by column panel, each row block reading the same panel
 * of W: the order the avx512bf16 kernel was written and timed in. */
static void gemm_bf16(const uint32_t *A, int lda2, int R, int K2, const uint32_t *W, int N, const float *bias,
                      float *C, int ldc) {
    for (int c0 = 0; c0 < N; c0 += PC_NB * PC_VW)
        for (int r0 = 0; r0 < R; r0 += PC_MR) gemm_block(1, A, lda2, K2, W, N, bias, C, ldc, r0, c0);
}

static inline int round_up(int n, int m) { return (n + m - 1) / m * m; }

static void decode_tile(const PcDecoder *d, const PcDecodeArgs *a, int64_t r0, int64_t r1,
                        float *scratch) {
    const int H = d->H, H3 = 3 * H, n = (int)(r1 - r0), R = round_up(n, PC_MR);
    float *f = scratch;                     /* (R, H) */
    float *hb = f + (size_t)PC_TILE * H;    /* (R, H) */
    float *gi = hb + (size_t)PC_TILE * H;   /* (R, 3H) */
    float *gh = gi + (size_t)PC_TILE * H3;  /* (R, 3H) */
    float *act = gh + (size_t)PC_TILE * H3; /* (R, H) */
    float *head = act + (size_t)PC_TILE * H; /* (R, PC_HEADW) */
    for (int r = 0; r < R; r++) {
        float *fr = f + (size_t)r * H, *hr = hb + (size_t)r * H;
        if (r >= n) {
            memset(fr, 0, sizeof(float) * H);
            memset(hr, 0, sizeof(float) * H);
            continue;
        }
        const int64_t row = r0 + r;
        const float *xp = a->xproj + (size_t)(row / a->group) * H;
        const float *zr = a->zc + (size_t)row * H;
        for (int c = 0; c < H; c += PC_VW)
            STOREA(fr + c, vmax(LOADU(xp + c) + LOADU(zr + c), splat(0.0f)));
        memcpy(hr, a->h + (size_t)row * H, sizeof(float) * H);
    }
    if (a->bf16 && d->bf16) {
        uint32_t *fb = (uint32_t *)(head + (size_t)PC_TILE * PC_HEADW);
        uint32_t *hbb = fb + (size_t)PC_TILE * H / 2;
        to_bf16(f, R, H, fb);
        to_bf16(hb, R, H, hbb);
        gemm_bf16(fb, H / 2, R, H / 2, d->wih_bf, H3, d->bih, gi, H3);
        gemm_bf16(hbb, H / 2, R, H / 2, d->whh_bf, H3, d->bhh, gh, H3);
    } else {
        gemm(f, H, R, H, d->wih, H3, d->bih, gi, H3);
        gemm(hb, H, R, H, d->whh, H3, d->bhh, gh, H3);
    }
    for (int r = 0; r < n; r++) {
        const float *gir = gi + (size_t)r * H3, *ghr = gh + (size_t)r * H3;
        const float *hr = hb + (size_t)r * H;
        float *ho = a->h_out + (size_t)(r0 + r) * H, *ar = act + (size_t)r * H;
        for (int c = 0; c < H; c += PC_VW) {
            vf rg = vsigmoid(LOADA(gir + c) + LOADA(ghr + c));
            vf ug = vsigmoid(LOADA(gir + H + c) + LOADA(ghr + H + c));
            vf ng = vtanh(LOADA(gir + 2 * H + c) + rg * LOADA(ghr + 2 * H + c));
            vf hn = ng + ug * (LOADA(hr + c) - ng);
            STOREU(ho + c, hn);
            STOREA(ar + c, vmax(hn, splat(0.0f)));
        }
    }
    for (int r = n; r < R; r++) memset(act + (size_t)r * H, 0, sizeof(float) * H);
    gemm(act, H, R, H, d->whead, PC_HEADW, d->bhead, head, PC_HEADW);
    const int nr = d->n_rot, nt = d->n_root;
    for (int r = 0; r < n; r++) {
        const float *hd = head + (size_t)r * PC_HEADW;
        const int64_t row = r0 + r;
        memcpy(a->rot + (size_t)row * nr, hd, sizeof(float) * nr);
        if (nt) memcpy(a->root + (size_t)row * nt, hd + nr, sizeof(float) * nt);
        for (int s = 0; s < 2; s++) a->con[row * 2 + s] = 1.0f / (1.0f + expf(-hd[nr + nt + s]));
    }
}

/* --- geometry: one row at a time, scalar (the compiler vectorises what it can) ----- */

static const int PARENT[PC_J] = {-1, 0, 1, 2, 3, 2, 5, 6, 2, 8, 9, 0, 11, 12, 13, 0, 15, 16, 17};
/* joints with children: their world rotation is needed for FK */
static const unsigned char HAS_CHILD[PC_J] = {1, 1, 1, 1, 0, 1, 1, 0, 1, 1, 0, 1, 1, 1, 0, 1, 1, 1, 0};
static const int LOWER[8] = {11, 12, 13, 14, 15, 16, 17, 18};

/* 6D (first two columns) -> row-major 3x3, Gram-Schmidt as batch_fk.r6d2mat32. */
static inline void r6d_mat(const float *d, float *m) {
    float a1x = d[0], a1y = d[1], a1z = d[2], a2x = d[3], a2y = d[4], a2z = d[5];
    float n1 = sqrtf(a1x * a1x + a1y * a1y + a1z * a1z);
    n1 = n1 > 1e-8f ? n1 : 1e-8f;
    float b1x = a1x / n1, b1y = a1y / n1, b1z = a1z / n1;
    float dt = b1x * a2x + b1y * a2y + b1z * a2z;
    float b2x = a2x - dt * b1x, b2y = a2y - dt * b1y, b2z = a2z - dt * b1z;
    float n2 = sqrtf(b2x * b2x + b2y * b2y + b2z * b2z);
    n2 = n2 > 1e-8f ? n2 : 1e-8f;
    b2x /= n2, b2y /= n2, b2z /= n2;
    float b3x = b1y * b2z - b1z * b2y, b3y = b1z * b2x - b1x * b2z, b3z = b1x * b2y - b1y * b2x;
    m[0] = b1x, m[1] = b2x, m[2] = b3x;
    m[3] = b1y, m[4] = b2y, m[5] = b3y;
    m[6] = b1z, m[7] = b2z, m[8] = b3z;
}

static inline void mat_mul(const float *a, const float *b, float *c) {
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++)
            c[i * 3 + k] = a[i * 3] * b[k] + a[i * 3 + 1] * b[3 + k] + a[i * 3 + 2] * b[6 + k];
}

static inline void place(const float *wm, const float *wp_parent, const float *off, float *out) {
    for (int i = 0; i < 3; i++)
        out[i] = wp_parent[i] + (wm[i * 3] * off[0] + wm[i * 3 + 1] * off[1] + wm[i * 3 + 2] * off[2]);
}

/* Positions of all 19 joints (out, 57 floats) from 108 rotation values. */
static void fk_row(const PcPool *w, const float *rot, const float *rm, const float *rp, float *out) {
    float wm[PC_J][9];
    memcpy(wm[0], rm, sizeof(float) * 9);
    memcpy(out, rp, sizeof(float) * 3);
    for (int j = 1; j < PC_J; j++) {
        const int p = PARENT[j];
        place(wm[p], out + 3 * p, w->offsets[j], out + 3 * j);
        if (HAS_CHILD[j]) {
            float loc[9];
            r6d_mat(rot + 6 * (j - 1), loc);
            mat_mul(wm[p], loc, wm[j]);
        }
    }
}

/* ik.two_bone_ik for one leg, in double as the reference computes it, without hint_m
 * (the contact IK passes none): hint (the thigh's forward axis, or NULL) keeps the
 * knee on its side of the hip-target line, a knee behind it mirrored to the front. */
static void two_bone(const double *hip, const double *knee, const double *ankle,
                     const double *target, const double *hint, double *k2, double *a2) {
    double e1[3], e2[3], to[3], bend[3];
    for (int i = 0; i < 3; i++) {
        e1[i] = knee[i] - hip[i];
        e2[i] = ankle[i] - knee[i];
        to[i] = target[i] - hip[i];
        bend[i] = knee[i] - hip[i];
    }
    double l1 = sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]);
    double l2 = sqrt(e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2]);
    double d = sqrt(to[0] * to[0] + to[1] * to[1] + to[2] * to[2]);
    double lo = fabs(l1 - l2) + 1e-6, hi = l1 + l2 - 1e-6;
    double dc = d < lo ? lo : d;
    dc = dc > hi ? hi : dc;
    double dn = d > 1e-9 ? d : 1e-9;
    double u[3] = {to[0] / dn, to[1] / dn, to[2] / dn};
    double bu = bend[0] * u[0] + bend[1] * u[1] + bend[2] * u[2];
    double v[3] = {bend[0] - bu * u[0], bend[1] - bu * u[1], bend[2] - bu * u[2]};
    double vn = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if (hint) {
        double hu = hint[0] * u[0] + hint[1] * u[1] + hint[2] * u[2];
        double h[3] = {hint[0] - hu * u[0], hint[1] - hu * u[1], hint[2] - hu * u[2]};
        double hn = sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
        hn = hn > 1e-9 ? hn : 1e-9;
        for (int i = 0; i < 3; i++) h[i] /= hn;
        double back = v[0] * h[0] + v[1] * h[1] + v[2] * h[2];
        back = back < 0.0 ? back : 0.0;
        for (int i = 0; i < 3; i++) v[i] -= 2.0 * back * h[i]; /* mirrored: same length */
    }
    if (vn > 1e-6) {
        for (int i = 0; i < 3; i++) v[i] /= vn;
    } else { /* a straight leg: bend forward (+Z) */
        double fu = u[2];
        double fb[3] = {-fu * u[0], -fu * u[1], 1.0 - fu * u[2]};
        double fn = sqrt(fb[0] * fb[0] + fb[1] * fb[1] + fb[2] * fb[2]);
        fn = fn > 1e-9 ? fn : 1e-9;
        for (int i = 0; i < 3; i++) v[i] = fb[i] / fn;
    }
    double ca = (l1 * l1 + dc * dc - l2 * l2) / (2 * l1 * dc);
    ca = ca < -1.0 ? -1.0 : (ca > 1.0 ? 1.0 : ca);
    double sa = sqrt(1.0 - ca * ca);
    for (int i = 0; i < 3; i++) {
        k2[i] = hip[i] + l1 * (ca * u[i] + sa * v[i]);
        a2[i] = hip[i] + u[i] * dc;
    }
}

/* ik.ContactIK.step for one row: positions only, as the candidate pool runs it
 * (fwd NULL), or with each thigh's forward axis fwd[2][3] for the shown pose, whose
 * knees never bend away from it. Returns which legs it moved (bit 0 left, bit 1
 * right). */
static int ik_row(const PcPoolArgs *a, int64_t row, float *wp, const double (*fwd)[3]) {
    int moved = 0;
    static const int LEG[2][4] = {{11, 12, 13, 14}, {15, 16, 17, 18}};
    const int rf = a->release_frames, den = rf > 1 ? rf : 1;
    for (int s = 0; s < 2; s++) {
        const int64_t i = row * 2 + s;
        const int thigh = LEG[s][0], shin = LEG[s][1], foot = LEG[s][2], toe = LEG[s][3];
        double *lock = a->lock_pos + i * 3;
        double feet[3] = {wp[3 * foot], wp[3 * foot + 1], wp[3 * foot + 2]};
        int pred = a->con[i] > 0.5f;
        int sup = a->suppressed[i] && pred && a->release[i] > 0; /* re-lock once blended back */
        int locked = a->locked[i];
        if (a->max_drift >= 0.0) {
            double dx = feet[0] - lock[0], dy = feet[1] - lock[1], dz = feet[2] - lock[2];
            if (locked && pred && sqrt(dx * dx + dy * dy + dz * dz) > a->max_drift) sup = 1;
        }
        int contact = pred && !sup;
        int64_t rel = a->release[i];
        if (contact && !locked) {
            double w = (double)rel / den;
            for (int k = 0; k < 3; k++) lock[k] = w * lock[k] + (1 - w) * feet[k];
        }
        if (!contact && locked) rel = rf;
        if (contact) rel = 0;
        a->locked[i] = (uint8_t)contact;
        a->suppressed[i] = (uint8_t)sup;
        int releasing = rel > 0;
        if (contact || releasing) {
            moved |= 1 << s;
            double w = (double)rel / den, target[3];
            for (int k = 0; k < 3; k++) target[k] = contact ? lock[k] : w * lock[k] + (1 - w) * feet[k];
            double hip[3], knee[3], k2[3], a2[3];
            for (int k = 0; k < 3; k++) {
                hip[k] = wp[3 * thigh + k];
                knee[k] = wp[3 * shin + k];
            }
            two_bone(hip, knee, feet, target, fwd ? fwd[s] : NULL, k2, a2);
            for (int k = 0; k < 3; k++) {
                float toe_off = wp[3 * toe + k] - wp[3 * foot + k];
                wp[3 * shin + k] = (float)k2[k];
                wp[3 * foot + k] = (float)a2[k];
                wp[3 * toe + k] = (float)(a2[k] + toe_off);
            }
        }
        if (releasing) rel -= 1;
        a->release[i] = rel;
    }
    return moved;
}

static void pool_tile(const PcPool *w, const PcPoolArgs *a, int64_t r0, int64_t r1, float *scratch) {
    const int n = (int)(r1 - r0), R = round_up(n, PC_MR), NJ = PC_J * 3;
    float *local = scratch;                           /* (R, 57) character-frame positions */
    float *x = local + (size_t)PC_TILE * NJ;          /* (R, 57) normalised */
    float *buf0 = x + (size_t)PC_TILE * NJ;           /* (R, PC_AE_MAXW) */
    float *buf1 = buf0 + (size_t)PC_TILE * PC_AE_MAXW;
    float *rootl = buf1 + (size_t)PC_TILE * PC_AE_MAXW; /* (R, 9) heading-free pelvis */
    for (int r = 0; r < n; r++) {
        const int64_t row = r0 + r, g = row / a->group;
        const float *rm = a->root_mat + g * 9, *rp = a->root_pos + g * 3;
        float *wp = a->wp + (size_t)row * NJ;
        fk_row(w, a->rot + (size_t)row * 108, rm, rp, wp);
        ik_row(a, row, wp, NULL);
        /* anomaly.score_mats: heading removed, origin on the floor under the pelvis */
        float yaw = atan2f(rm[2], rm[8]), c = cosf(yaw), s = sinf(yaw);
        float iy[9] = {c, 0.0f, -s, 0.0f, 1.0f, 0.0f, s, 0.0f, c};
        mat_mul(iy, rm, rootl + (size_t)r * 9);
        float ca = cosf(-yaw), sa = sinf(-yaw);
        float *lr = local + (size_t)r * NJ, *xr = x + (size_t)r * NJ;
        for (int j = 0; j < PC_J; j++) {
            float px = wp[3 * j] - rp[0], py = wp[3 * j + 1], pz = wp[3 * j + 2] - rp[2];
            lr[3 * j] = ca * px + sa * pz;
            lr[3 * j + 1] = py;
            lr[3 * j + 2] = -sa * px + ca * pz;
        }
        for (int k = 0; k < NJ; k++) xr[k] = (lr[k] - w->mean[k]) * w->inv_std[k];
    }
    for (int r = n; r < R; r++) memset(x + (size_t)r * NJ, 0, sizeof(float) * NJ);
    /* the autoencoder, one tile at a time */
    const float *in = x;
    int ld = NJ;
    float *out = buf0;
    for (int l = 0; l < PC_AE_LAYERS; l++) {
        const PcLayer *L = &w->layers[l];
        gemm(in, ld, R, L->k, L->w, L->np, L->b, out, L->np);
        if (l < PC_AE_LAYERS - 1)
            for (int i = 0; i < R * L->np; i += PC_VW) STOREA(out + i, vmax(LOADA(out + i), splat(0.0f)));
        in = out;
        ld = L->np;
        out = out == buf0 ? buf1 : buf0;
    }
    /* reconstruction: FK of the lower body from the AE's rotations, error per row */
    for (int r = 0; r < n; r++) {
        const float *rot = in + (size_t)r * ld, *lr = local + (size_t)r * NJ;
        float wm[PC_J][9], pos[PC_J * 3];
        memcpy(wm[0], rootl + (size_t)r * 9, sizeof(float) * 9);
        memcpy(pos, lr, sizeof(float) * 3);
        for (int j = 11; j < PC_J; j++) {
            const int p = PARENT[j];
            place(wm[p], pos + 3 * p, w->offsets[j], pos + 3 * j);
            if (HAS_CHILD[j]) {
                float loc[9];
                r6d_mat(rot + 6 * (j - 1), loc);
                mat_mul(wm[p], loc, wm[j]);
            }
        }
        float err = 0.0f;
        for (int q = 0; q < 8; q++) {
            const int j = LOWER[q];
            float dx = pos[3 * j] - lr[3 * j], dy = pos[3 * j + 1] - lr[3 * j + 1],
                  dz = pos[3 * j + 2] - lr[3 * j + 2];
            err += sqrtf(dx * dx + dy * dy + dz * dz);
        }
        a->scores[r0 + r] = err / 8.0f;
    }
}

/* --- the shown pose: FK with rotations, the display IK, quaternions ------------------ */

/* rotations.mat2quat (pc_geom.h) of a float matrix, as floats. */
static void mat_quat(const float *mf, float *q) {
    double m[9], qd[4];
    for (int i = 0; i < 9; i++) m[i] = mf[i];
    pc_mat2quat(m, qd);
    for (int i = 0; i < 4; i++) q[i] = (float)qd[i];
}

/* One shown pose: positions (57) and world rotations as quaternions (76), after the
 * player's own display IK (ik.ContactIK.step with rotations: thigh and shin swing). */
static void emit_row(const PcPool *w, const PcPoolArgs *a, int64_t row, float *quat) {
    static const int LEG[2][4] = {{11, 12, 13, 14}, {15, 16, 17, 18}};
    const float *rot = a->rot + (size_t)row * 108;
    float wm[PC_J][9], *wp = a->wp + (size_t)row * PC_J * 3;
    memcpy(wm[0], a->root_mat + row * 9, sizeof(float) * 9);
    memcpy(wp, a->root_pos + row * 3, sizeof(float) * 3);
    for (int j = 1; j < PC_J; j++) {
        const int p = PARENT[j];
        place(wm[p], wp + 3 * p, w->offsets[j], wp + 3 * j);
        float loc[9];
        r6d_mat(rot + 6 * (j - 1), loc);
        mat_mul(wm[p], loc, wm[j]);
    }
    float before[PC_J * 3];
    memcpy(before, wp, sizeof(before));
    double fwd[2][3]; /* each thigh's forward axis: its world rotation's third column */
    for (int s = 0; s < 2; s++)
        for (int k = 0; k < 3; k++) fwd[s][k] = wm[LEG[s][0]][3 * k + 2];
    const int moved = ik_row(a, row, wp, fwd); /* positions and state, knees forward */
    for (int s = 0; s < 2; s++) {
        const int thigh = LEG[s][0], shin = LEG[s][1], foot = LEG[s][2];
        if (!(moved >> s & 1)) continue;
        double hip[3], knee[3], ankle[3], k2[3], a2[3], d1[3], d2[3], d3[3], d4[3];
        for (int k = 0; k < 3; k++) {
            hip[k] = before[3 * thigh + k], knee[k] = before[3 * shin + k], ankle[k] = before[3 * foot + k];
            k2[k] = wp[3 * shin + k], a2[k] = wp[3 * foot + k];
            d1[k] = knee[k] - hip[k], d2[k] = k2[k] - hip[k];
        }
        double st[9], ss[9], sw[9], t[9], u[9], wt[9], ws[9], dir[3];
        pc_swing(d1, d2, st);
        for (int k = 0; k < 3; k++) d3[k] = ankle[k] - knee[k];
        for (int i = 0; i < 3; i++) dir[i] = st[i * 3] * d3[0] + st[i * 3 + 1] * d3[1] + st[i * 3 + 2] * d3[2];
        for (int k = 0; k < 3; k++) d4[k] = a2[k] - k2[k];
        pc_swing(dir, d4, sw);
        pc_mm(sw, st, ss);
        for (int i = 0; i < 9; i++) wt[i] = wm[thigh][i], ws[i] = wm[shin][i];
        pc_mm(st, wt, t);
        pc_mm(ss, ws, u);
        for (int i = 0; i < 9; i++) wm[thigh][i] = (float)t[i], wm[shin][i] = (float)u[i];
    }
    for (int j = 0; j < PC_J; j++) mat_quat(wm[j], quat + 4 * j);
}

static void emit_tile(const PcPool *w, const PcPoolArgs *a, int64_t r0, int64_t r1, float *scratch) {
    for (int64_t r = r0; r < r1; r++) emit_row(w, a, r, a->quat + r * PC_J * 4);
}

const PcKernels PC_TABLE = {PC_NAME, decode_tile, pool_tile, emit_tile};
