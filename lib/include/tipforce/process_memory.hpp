#pragma once
// How a process that runs the inversion should hand memory back to the system: not at all.

namespace tipforce {

// Keeps freed heap memory in the process for the next allocation instead of returning it to the
// system (glibc: large blocks from the heap, not from mmap, and no trimming). Each window
// allocates its batches' buffers afresh (a physics grid's 120 sets: ~1 MB); with glibc's
// defaults such a block was mapped and unmapped each time, and every page faulted in and zeroed
// again on first touch: a cold search's grid batch took 2.2-5.9 ms against its usual 0.85 ms
// (tipforce invert of bench_daemon's stream, three runs), enough to put a window past its
// latency budget. Call it once, first thing in main(), in a program that inverts windows under a
// deadline (tipforced, tipforce invert). It changes the allocator of the whole process, so the
// library never calls it itself. Returns whether the allocator took the settings; elsewhere
// than glibc it does nothing and returns false.
bool keep_freed_memory_in_process();

}  // namespace tipforce
