/* posecast native SSI kernels: shared definitions.
 *
 * One tick hands the kernels all R = P * N candidate rows. Two kernels, each a
 * function of a contiguous row range [r0, r1) (a tile of at most PC_TILE rows), so
 * the thread pool (pc_threads.c) can hand tiles to any thread:
 *
 *   decode: the CVAE decoder step (first layer from a per-player tracker part and a
 *           per-row latent part, GRU gates, ReLU, pose/root/contact heads);
 *   pool:   6D -> matrices, FK, foot-contact IK, and the anomaly error of every row;
 *   emit:   the shown poses: FK with world rotations, the display IK (thigh and shin
 *           swing with the feet), quaternions.
 *
 * The same source (pc_impl.h) is compiled once per instruction-set level, each in
 * its own file with its own target pragma; pc_levels.c picks one at load time.
 */
#ifndef PC_KERNELS_H
#define PC_KERNELS_H

#include <stdint.h>
#include <string.h>

#define PC_J 19           /* joints */
#define PC_NROT 18        /* rotated joints (all but the pelvis) */
#define PC_HEADW 128      /* the pose + root + contact heads, padded */
#define PC_TILE 48        /* rows per tile: a multiple of every MR below */
#define PC_AE_LAYERS 7
#define PC_AE_MAXW 128    /* widest AE layer, padded */
#define PC_ALIGN 64

typedef struct {
    int F, H;             /* features, hidden width (a multiple of 64) */
    int n_rot, n_root;    /* 108, and 0 or 9 (a model that predicts the pelvis) */
    float *mean, *inv_std;  /* (F) feature normalisation */
    float *wx, *bfc;        /* (F, H), (H): the tracker part of the first layer */
    float *wih, *whh;       /* (H, 3H) row-major, gates r | u | n */
    float *bih, *bhh;       /* (3H) */
    float *whead, *bhead;   /* (H, PC_HEADW), (PC_HEADW): rot | root | contact | 0 */
    uint32_t *wih_bf, *whh_bf; /* (H/2, 3H) bf16 pairs (k even low, k odd high) */
    int bf16;               /* 1: the bf16 pairs are packed (the precision is the call's) */
} PcDecoder;

typedef struct {
    int k, n, np;           /* inputs, outputs, outputs padded to a multiple of 64 */
    float *w, *b;           /* (k, np), (np) */
} PcLayer;

typedef struct {
    float offsets[PC_J][3];
    float mean[PC_J * 3], inv_std[PC_J * 3];
    PcLayer layers[PC_AE_LAYERS];
} PcPool;

typedef struct {
    const float *xproj;     /* (G, H): normalised features x wx + bfc, per group */
    int64_t group;          /* rows per group */
    const float *zc;        /* (R, H): the latent part of the first layer */
    const float *h;         /* (R, H) */
    float *rot, *root, *con, *h_out; /* (R, n_rot), (R, n_root) or NULL, (R, 2), (R, H) */
    int bf16;               /* 1: the GRU gates in bf16 arithmetic (see pc_bf16_bits) */
} PcDecodeArgs;

typedef struct {
    const float *rot, *con;             /* (R, 108), (R, 2) */
    const float *root_mat, *root_pos;   /* (G, 9), (G, 3) */
    int64_t group;
    uint8_t *locked, *suppressed;       /* (R, 2) */
    double *lock_pos;                   /* (R, 2, 3) */
    int64_t *release;                   /* (R, 2) */
    int release_frames;
    double max_drift;                   /* < 0: never release early */
    float *wp;                          /* (R, 19, 3) out */
    double *scores;                     /* (R) out (pool) */
    float *quat;                        /* (R, 19, 4) out (emit): world rotations, xyzw */
} PcPoolArgs;

typedef struct {
    const char *name;
    void (*decode)(const PcDecoder *, const PcDecodeArgs *, int64_t r0, int64_t r1, float *scratch);
    void (*pool)(const PcPool *, const PcPoolArgs *, int64_t r0, int64_t r1, float *scratch);
    void (*emit)(const PcPool *, const PcPoolArgs *, int64_t r0, int64_t r1, float *scratch);
} PcKernels;

/* float32 -> bf16 bits as vcvtne2ps2bf16 converts: round to nearest even, zero and
 * denormals to a zero of their sign, inf as is, NaN quiet. The bf16 weights are packed
 * with it and the levels without the instruction convert the gates' inputs with it. */
static inline uint32_t pc_bf16_bits(float x) {
    uint32_t u;
    memcpy(&u, &x, 4);
    if ((u & 0x7f800000u) == 0) return (u >> 16) & 0x8000u;                       /* 0, denormal */
    if ((u & 0x7f800000u) == 0x7f800000u) return (u >> 16) | ((u & 0x7fffffu) ? 0x40u : 0u); /* inf, NaN */
    u += 0x7fffu + ((u >> 16) & 1u);                                            /* nearest even */
    return u >> 16;
}

/* Bytes of scratch one thread needs for either kernel (H <= 256, checked at pack time). */
#define PC_SCRATCH_BYTES (1u << 20)

extern const PcKernels pc_kernels_generic;
#if defined(__x86_64__) || defined(_M_X64)
extern const PcKernels pc_kernels_avx2;
extern const PcKernels pc_kernels_avx512;
extern const PcKernels pc_kernels_avx512bf16;
#endif

#endif
