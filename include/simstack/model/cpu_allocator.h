#pragma once
/// @file cpu_allocator.h
/// Process-wide allocator settings for running libtorch on the CPU.

namespace simstack {

/// libtorch's CPU allocator does not cache: with glibc's defaults every large tensor is a fresh
/// mmap that page-faults on first touch (much of training's time goes to the kernel). This keeps
/// freed memory in the heap for reuse instead (no mmap for large blocks, no trimming; the speed-up:
/// docs/experiments.md, "Runtime (threads, allocator)"). It changes glibc's
/// malloc for the whole process, so programs call it once at the start of main(); a library
/// never does it on its own.
void keepFreedMemoryForReuse();

}  // namespace simstack
