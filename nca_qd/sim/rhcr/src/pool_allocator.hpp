// An allocator that serves single-object allocations from a per-thread free list (one list per
// object size) and everything else from operator new. Node-based containers that are filled and
// emptied many times per second (PBS's set of agents to replan) then stop calling malloc once
// warm. Which addresses they get does not change what they hold or the order they iterate in.
#pragma once

#include <cstddef>
#include <new>
#include <vector>

namespace rhcr {

template <std::size_t Size>
struct FreeList {
  static std::vector<void*>& list() {
    thread_local std::vector<void*> blocks;  // simulations run in parallel threads
    return blocks;
  }
};

template <class T>
struct PoolAllocator {
  using value_type = T;
  PoolAllocator() noexcept = default;
  template <class U>
  PoolAllocator(const PoolAllocator<U>&) noexcept {}

  T* allocate(std::size_t n) {
    if (n == 1) {
      auto& blocks = FreeList<sizeof(T)>::list();
      if (!blocks.empty()) {
        void* p = blocks.back();
        blocks.pop_back();
        return static_cast<T*>(p);
      }
    }
    return static_cast<T*>(::operator new(n * sizeof(T)));
  }
  void deallocate(T* p, std::size_t n) noexcept {
    if (n == 1) {
      auto& blocks = FreeList<sizeof(T)>::list();
      if (blocks.size() < 4096) {
        blocks.push_back(p);
        return;
      }
    }
    ::operator delete(p);
  }
  template <class U>
  bool operator==(const PoolAllocator<U>&) const noexcept { return true; }
  template <class U>
  bool operator!=(const PoolAllocator<U>&) const noexcept { return false; }
};

}  // namespace rhcr
