// SPDX-License-Identifier: MIT
// test_memory.cpp — memory checked before it is spent: sparse files, decompression bombs, ray counts, allocation failures.
#include <catch2/catch.hpp>

#include "tests/helpers.h"
