// SPDX-License-Identifier: MIT
// build_stamp.h — which build a backend's uploaded copy is of, so a device or peer backend
// uploads a build once and again only when the Accel it traces has changed.
#pragma once
#include <cstdint>

#include "mbvh/accel.h"

namespace mbvh {

/// The build a backend's copy (device buffers, a peer library's scene) was made from: the Accel
/// object, its hash and its generation (Accel::generation: refit bumps it). Empty: no copy.
struct BuildStamp {
  const Accel* acc = nullptr;
  std::uint64_t hash = 0;
  std::uint64_t generation = 0;

  /// Whether the copy is not of `a` as it is now: another object, another build, refitted since,
  /// or no copy at all.
  bool stale(const Accel& a) const { return &a != acc || a.hash() != hash || a.generation() != generation; }
  /// Records that the copy is of `a` as it is now.
  void mark(const Accel& a) {
    acc = &a;
    hash = a.hash();
    generation = a.generation();
  }
};

}  // namespace mbvh
