// CPU seconds used by the calling thread (planning-call limits and the reported costs).
#pragma once

#include <time.h>

namespace rhcr {

inline double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

}  // namespace rhcr
