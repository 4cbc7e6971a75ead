// SPDX-License-Identifier: MIT
// test_cache_safety.cpp — the BVH cache under hostile use: links, crafted and colliding entries, concurrent writers, sizes checked before allocating.
#include <catch2/catch.hpp>

#include "tests/helpers.h"
