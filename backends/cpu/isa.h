// SPDX-License-Identifier: MIT
// isa.h — the per-ISA translation unit's switches: MBVH_ISA_BEGIN ... MBVH_ISA_END compile the
// functions defined between them for the ISA the build names (MBVH_CPU_ISA_ID), by a target
// pragma rather than TU-wide -m flags (isa_kernels.cpp says why).
#pragma once

#ifndef MBVH_CPU_ISA
#error "compile with -DMBVH_CPU_ISA=avx2|avx512, -DMBVH_CPU_ISA_ID=1|2 and -DMBVH_ISA_NS=<the ISA>"
#endif

#if MBVH_CPU_ISA_ID == 2
#define MBVH_ISA_TARGET "avx2,fma,avx512f,avx512vl,avx512dq,avx512bw"
#else
#define MBVH_ISA_TARGET "avx2,fma"  // FMA only in the fast mode's explicit intrinsics (-ffp-contract=off)
#endif
#define MBVH_PRAGMA(x) _Pragma(#x)
#if defined(__clang__)
#define MBVH_ISA_PUSH(t) MBVH_PRAGMA(clang attribute push(__attribute__((target(t))), apply_to = function))
#define MBVH_ISA_END _Pragma("clang attribute pop")
#else
#define MBVH_ISA_PUSH(t) _Pragma("GCC push_options") MBVH_PRAGMA(GCC target(t))
#define MBVH_ISA_END _Pragma("GCC pop_options")
#endif
#define MBVH_ISA_BEGIN MBVH_ISA_PUSH(MBVH_ISA_TARGET)

#define MBVH_STR2(x) #x
#define MBVH_STR(x) MBVH_STR2(x)
