// SPDX-License-Identifier: MIT
// test_range.cpp — exact or refused: triangles and rays at the ends of the traced range, check's ties at tmin.
#include <catch2/catch.hpp>

#include "tests/helpers.h"
