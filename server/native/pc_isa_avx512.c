/* AVX-512F: 16-float vectors, a 6 x 64 register block (24 accumulators), fp32. */
#if defined(__x86_64__) || defined(_M_X64)
#pragma GCC target("avx512f,avx512dq,avx512bw,avx512vl,fma")
#define PC_VW 16
#define PC_MR 6
#define PC_NB 4
#include <immintrin.h>
#define PC_SPLAT(x) _mm512_set1_ps(x)
#define PC_RCP(x) _mm512_rcp14_ps((__m512)(x))
#define PC_BF16 0
#define PC_NAME "avx512f"
#define PC_TABLE pc_kernels_avx512
#include "pc_impl.h"
#endif
