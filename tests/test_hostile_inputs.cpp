// SPDX-License-Identifier: MIT
// test_hostile_inputs.cpp — library misuse, loaders and CLI options under hostile input.
#include <catch2/catch.hpp>

#include "tests/helpers.h"
