#include "deblur_sr_mvs/core/common/runtime.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>

namespace deblur_sr_mvs {
namespace {

#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33))
// An image-sized block (16 MiB, a 640x480 RGB float image is 3.5 MiB, an
// operator up to about 30 MiB) freed after KeepFreedMemoryForReuse stays in
// the heap as free memory for the next allocation instead of going back to
// the kernel (glibc's default would mmap and unmap it, or trim it).
TEST(Runtime, FreedImageSizedBlocksStayInTheHeap) {
  ASSERT_TRUE(KeepFreedMemoryForReuse());
  constexpr size_t kBytes = size_t{16} << 20;
  char* block = static_cast<char*>(std::malloc(kBytes));
  ASSERT_NE(block, nullptr);
  std::memset(block, 1, kBytes);  // touch the pages
  const size_t heap_before_free = mallinfo2().arena;
  EXPECT_GE(heap_before_free, kBytes) << "the block did not come from the heap";
  std::free(block);
  const struct mallinfo2 after = mallinfo2();
  EXPECT_EQ(after.arena, heap_before_free) << "the heap was trimmed";
  EXPECT_GE(after.fordblks, kBytes) << "the freed block is not kept as free heap memory";
}
#elif !defined(__GLIBC__)
TEST(Runtime, KeepFreedMemoryForReuseIsANoOpWithoutGlibc) {
  EXPECT_FALSE(KeepFreedMemoryForReuse());
}
#endif

}  // namespace
}  // namespace deblur_sr_mvs
