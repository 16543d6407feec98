/* The portable level: plain C with 4-float vectors (SSE2 on x86-64, NEON on ARM). */
#define PC_VW 4
#define PC_MR 4
#define PC_NB 2
#if defined(__SSE2__)
#include <immintrin.h>
#define PC_SPLAT(x) _mm_set1_ps(x)
#elif defined(__ARM_NEON)
#include <arm_neon.h>
#define PC_SPLAT(x) vdupq_n_f32(x)
#else
#define PC_SPLAT(x) ((float __attribute__((vector_size(16)))){(x), (x), (x), (x)})
#endif
#define PC_BF16 0
#define PC_NAME "generic"
#define PC_TABLE pc_kernels_generic
#include "pc_impl.h"
