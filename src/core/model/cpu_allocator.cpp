#include "simstack/model/cpu_allocator.h"

#include <malloc.h>

namespace simstack {

void keepFreedMemoryForReuse() {
  mallopt(M_MMAP_MAX, 0);         // large blocks from the heap, not from mmap
  mallopt(M_TRIM_THRESHOLD, -1);  // and never handed back to the kernel
}

}  // namespace simstack
