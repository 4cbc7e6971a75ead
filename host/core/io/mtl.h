// SPDX-License-Identifier: MIT
// mtl.h — the diffuse colours of an OBJ file's materials, from the MTL libraries it names.
#pragma once
#include <string>
#include <vector>

#include "host/core/io/obj.h"
#include "mbvh/scene.h"

namespace mbvh {

/// Gives `s.materials` (the OBJ file's `usemtl` names) their `Kd` colours from the MTL files
/// `libraries` names, each resolved against the directory of `obj_path` (a name not found there
/// is also looked for with ".zst" appended; either may be zstd-compressed). Materials stay the
/// renderer's grey where no colour is found, and that is never an error: a library that is
/// missing or unreadable, a Kd line it cannot read, and `usemtl` names no library defines each
/// give one warning line through log_message naming the file (and line). Kd values above 1 are
/// clamped to 1. Reads nothing when the scene uses no material.
void read_materials(Scene& s, const std::string& obj_path, const std::vector<ObjParser::Library>& libraries);

}  // namespace mbvh
