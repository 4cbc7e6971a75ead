// SPDX-License-Identifier: MIT
// huge_pages.h — transparent huge pages for the build's large arrays (advise_huge_pages, defined
// in resources.cpp beside the other process-memory helpers).
#pragma once
#include <cstddef>

namespace mbvh {

/// Asks the kernel to back the whole huge pages (2 MiB on x86-64: the kernel's PMD size) inside
/// [p, p + bytes) with transparent huge pages (Linux: madvise MADV_HUGEPAGE, which takes effect
/// where THP is "always" or "madvise"; nothing where it is "never", where MBVH_HUGE_PAGES=0 is set,
/// or off Linux): the first touch of such a page is one fault that maps 2 MiB instead of 512
/// faults of 4 KiB each. For a large array before its pages are first written, when it is written
/// in full or from its start (a page is only made resident when touched, a huge one in full: an
/// array touched here and there would hold untouched 4 KiB pages). The parts outside whole 2 MiB
/// pages keep 4 KiB pages; it never fails (the advice is a hint).
void advise_huge_pages(const void* p, std::size_t bytes);

}  // namespace mbvh
