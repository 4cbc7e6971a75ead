// main.cpp — the Catch2 main of mbvh-tests.
#define CATCH_CONFIG_MAIN
#include <catch2/catch.hpp>
