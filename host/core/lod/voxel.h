// SPDX-License-Identifier: MIT
// voxel.h — the packed attributes of an LOD voxel face (format.h, Voxel::face): an octahedral
// unit normal in two snorm8 (Cigolle, Donow, Evangelakos, Mara, McGuire & Sharpe, "A Survey of
// Efficient Representations for Independent Unit Vectors", JCGT 3(2), 2014) and an RGB565 albedo.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "mbvh/scene.h"

namespace mbvh::lod {

inline std::uint32_t snorm8(float x) {
  const float c = std::clamp(x, -1.0f, 1.0f);
  return static_cast<std::uint32_t>(static_cast<std::int32_t>(std::lround(c * 127.0f)) & 0xff);
}
inline float unsnorm8(std::uint32_t b) {
  return std::max(-1.0f, static_cast<float>(static_cast<std::int8_t>(static_cast<std::uint8_t>(b))) / 127.0f);
}

/// 16 bits: the octahedral encoding of n (any length > 0; a zero vector encodes +z).
inline std::uint32_t encode_normal(Vec3f n) {
  const float s = std::fabs(n.x) + std::fabs(n.y) + std::fabs(n.z);
  if (!(s > 0)) return snorm8(0) | snorm8(0) << 8;
  float x = n.x / s, y = n.y / s;
  if (n.z < 0) {
    const float ox = (1 - std::fabs(y)) * (x >= 0 ? 1.0f : -1.0f);
    const float oy = (1 - std::fabs(x)) * (y >= 0 ? 1.0f : -1.0f);
    x = ox, y = oy;
  }
  return snorm8(x) | snorm8(y) << 8;
}
/// The unit normal of encode_normal's 16 bits.
inline Vec3f decode_normal(std::uint32_t bits) {
  float x = unsnorm8(bits & 0xff), y = unsnorm8((bits >> 8) & 0xff);
  const float z = 1 - std::fabs(x) - std::fabs(y);
  if (z < 0) {
    const float ox = (1 - std::fabs(y)) * (x >= 0 ? 1.0f : -1.0f);
    const float oy = (1 - std::fabs(x)) * (y >= 0 ? 1.0f : -1.0f);
    x = ox, y = oy;
  }
  const float len = std::sqrt(x * x + y * y + z * z);
  return {x / len, y / len, z / len};
}

/// 16 bits: RGB565 of a linear colour in [0, 1] per channel.
inline std::uint32_t encode_rgb565(Vec3f c) {
  const auto q = [](float v, float m) { return static_cast<std::uint32_t>(std::lround(std::clamp(v, 0.0f, 1.0f) * m)); };
  return q(c.x, 31) << 11 | q(c.y, 63) << 5 | q(c.z, 31);
}
inline Vec3f decode_rgb565(std::uint32_t bits) {
  return {static_cast<float>((bits >> 11) & 31) / 31.0f, static_cast<float>((bits >> 5) & 63) / 63.0f,
          static_cast<float>(bits & 31) / 31.0f};
}

/// A face's 32 bits (format.h Voxel::face): normal low, albedo high.
inline std::uint32_t pack_face(Vec3f normal, Vec3f albedo) { return encode_normal(normal) | encode_rgb565(albedo) << 16; }

}  // namespace mbvh::lod
