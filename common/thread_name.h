// Names the calling thread as `top -H`, `ps -L`, perf and debuggers show it (Linux: at most 15
// characters; longer names are cut). Purely diagnostic: a failure is ignored.
#pragma once

#include <pthread.h>

#include <string>

namespace epr {

inline void set_thread_name(const std::string& name) {
  (void)pthread_setname_np(pthread_self(), name.substr(0, 15).c_str());
}

}  // namespace epr
