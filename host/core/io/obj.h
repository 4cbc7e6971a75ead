// SPDX-License-Identifier: MIT
// obj.h — the Wavefront OBJ parser, fed the file piece by piece as it is read (parse_obj feeds it
// one buffer): it holds the scene parsed so far and one partial line, and checks that against the
// memory budget at every piece, so an input costs what its geometry costs, never its size.
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "host/core/resources.h"
#include "mbvh/scene.h"

namespace mbvh {

class ObjParser {
 public:
  /// `name` is used in error messages; `budget` bounds what the parse may hold.
  explicit ObjParser(std::string name, MemoryBudget budget = memory_budget());
  /// Parses the next piece of the file (split anywhere, even inside a line). Throws Error naming
  /// the file and line on malformed input (a NUL byte is refused as soon as its piece arrives),
  /// and naming the file and the estimate when the scene so far, one build of it and the
  /// partial line exceed the budget.
  void feed(const char* data, std::size_t size);
  /// The last line (one without a line end), the check of forward vertex indices, the scene
  /// (with its `usemtl` names as materials, grey until read_materials gives them colours).
  Scene finish();

  /// An `mtllib` file name and the line that named it.
  struct Library { std::string file; std::size_t line; };
  /// The `mtllib` file names read so far, in file order.
  const std::vector<Library>& material_libraries() const { return libraries_; }

 private:
  void refuse_binary(const char* data, std::size_t size) const;
  void parse_line(const char* p, const char* next);  // one line, [p, next), next excluded
  void check_budget() const;

  struct Pending { std::size_t tri, line; long long index; };
  std::string name_;
  MemoryBudget budget_;
  Scene s_;
  std::string partial_;             // the bytes of a line whose end has not arrived yet
  std::size_t line_ = 0;            // lines parsed
  std::uint64_t bytes_ = 0;         // bytes fed
  char first_[2] = {0, 0};          // the file's first two bytes (a UTF-16 byte-order mark?)
  std::vector<Pending> forward_;    // positive indices beyond the vertices read so far
  std::vector<std::uint32_t> face_;
  std::vector<Library> libraries_;
  std::unordered_map<std::string, std::uint32_t> material_index_;  // usemtl name -> s_.materials
  std::uint32_t material_ = kNoMaterial;                            // the current usemtl
};

}  // namespace mbvh
