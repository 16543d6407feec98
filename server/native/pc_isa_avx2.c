/* AVX2 + FMA: 8-float vectors, a 6 x 16 register block (12 accumulators). */
#if defined(__x86_64__) || defined(_M_X64)
#pragma GCC target("avx2,fma")
#define PC_VW 8
#define PC_MR 6
#define PC_NB 2
#include <immintrin.h>
#define PC_SPLAT(x) _mm256_set1_ps(x)
#define PC_RCP(x) _mm256_rcp_ps((__m256)(x))
#define PC_BF16 0
#define PC_NAME "avx2"
#define PC_TABLE pc_kernels_avx2
#include "pc_impl.h"
#endif
