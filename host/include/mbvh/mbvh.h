// SPDX-License-Identifier: MIT
// mbvh.h — the core's one header (mbvh::core): scenes (mbvh/scene.h), the build (mbvh/accel.h),
// rays, hits and trace options (mbvh/trace.h), the backend interface and its registry
// (mbvh/backend.h), ray-by-ray comparison of answers with classified ties (mbvh/compare.h), the caller's meshes, geometry-id hits and one-ray calls (mbvh/geometry.h), the
// ray / hit files (mbvh/rays.h), errors (mbvh/error.h) and the version (mbvh/version.h:
// MBVH_VERSION_STRING, mbvh::version()). The calls that register backends are defined by the
// backend libraries, not the core: a program that links them includes <mbvh/backends.h> too.
//
// Rules: every function throws mbvh::Error on failure (never exits). An Accel is immutable after
// build (refit excepted) and may be traced from several threads at once; a Backend object may be
// called from several threads, and its calls run one at a time (make one per thread to trace in
// parallel). A ray outside the exactly traced range is refused (check_ray_range in
// mbvh/trace.h), an invalid one is a defined miss. Nothing keeps a pointer to
// the caller's arrays after the call returns, except a Scene's mesh views (Scene::add_mesh; the
// rules atop mbvh/geometry.h).
#pragma once
#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/compare.h"
#include "mbvh/config.h"
#include "mbvh/error.h"
#include "mbvh/geometry.h"
#include "mbvh/instance.h"
#include "mbvh/log.h"
#include "mbvh/rays.h"
#include "mbvh/scene.h"
#include "mbvh/tasks.h"
#include "mbvh/trace.h"
#include "mbvh/version.h"
