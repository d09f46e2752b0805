// Linked into the ThreadSanitizer build's test binaries and programs (epr, epr-master, epr-worker;
// tests/CMakeLists.txt, scripts/tsan.sh): TBB runs every parallel loop on the thread that calls it.
// Debian's TBB is not instrumented, so TSan cannot see a loop's hand-off to TBB's worker threads;
// every access of those workers to the caller's data is reported and then suppressed
// (scripts/tsan.supp, race:tbb::detail::), and restoring the stacks of those reports made the tests
// run for minutes. On the calling thread the same code is checked against the project's own threads
// instead.
#include <tbb/global_control.h>

namespace {
const tbb::global_control serial_tbb(tbb::global_control::max_allowed_parallelism, 1);
}  // namespace
