// Child processes for the multi-process tests: spawned with stdout and stderr going to files, waited
// for with a deadline, and always gone when their Process object is (SIGTERM, then SIGKILL).
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace epr::testing {

using Millis = std::chrono::milliseconds;

/// What a child gets besides this process's environment.
struct ProcessOptions {
  std::vector<std::string> env;  // NAME=VALUE, set in the child (over this process's value)
  // > 0: the child's RLIMIT_FSIZE, with SIGXFSZ ignored: a write past it fails with EFBIG (a full
  // disk, for one process, that works as root too). Its logs count: keep them under it.
  uint64_t file_size_limit = 0;
};

/// A running (or finished) child process. Not copyable; the destructor ends and reaps it.
class Process {
 public:
  /// Starts argv[0] (a path) with argv and this process's environment; stdin is /dev/null, stdout
  /// goes to `log_prefix`.out and stderr to `log_prefix`.err. The child gets SIGKILL if this process
  /// dies first. Throws std::runtime_error if the program cannot be started.
  Process(std::vector<std::string> argv, const std::filesystem::path& log_prefix, const ProcessOptions& options = {});
  ~Process();
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  pid_t pid() const { return pid_; }
  const std::string& name() const { return name_; }
  /// True while the child has not exited (reaps it if it has).
  bool running();
  /// Waits up to `timeout` for the child to exit. Its exit code (128 + signal if killed by one), or
  /// nullopt if it is still running at the deadline.
  std::optional<int> wait_for(Millis timeout);
  /// Sends `sig` (no-op once the child has been reaped).
  void signal(int sig);
  /// SIGTERM, up to `grace` for the child to exit, then SIGKILL; returns the exit code.
  int stop(Millis grace = Millis(5000));
  /// Exit code once reaped.
  std::optional<int> exit_code() const { return exit_code_; }

  std::string out() const;  // everything written to stdout so far
  std::string err() const;  // everything written to stderr so far
  const std::filesystem::path& err_path() const { return err_path_; }

 private:
  bool reap(bool block);

  std::string name_;
  std::filesystem::path out_path_, err_path_;
  pid_t pid_ = -1;
  std::optional<int> exit_code_;
};

/// What a program that ran to the end left behind.
struct RunResult {
  int code = -1;  // exit code, 128 + signal if killed
  bool timed_out = false;
  double seconds = 0;  // wall clock
  std::string out, err;
};

/// Runs argv to completion (killed at `timeout`, then timed_out is set).
RunResult run_process(std::vector<std::string> argv, const std::filesystem::path& log_prefix, Millis timeout);

/// Polls `done` every 20 ms until it returns true or `timeout` passes; returns its last answer.
bool wait_until(const std::function<bool()>& done, Millis timeout);

/// Waits up to `timeout` for epr-master `master` to log "listening on port N" (or to exit); N, or 0
/// if it did not.
int listening_port(Process& master, Millis timeout);

/// Starts epr-master with `argv` into `master` and waits up to 10 s for its port. A port just freed
/// by a killed master may take a moment to be bindable again, so it tries up to 20 times, 250 ms
/// apart; `log_prefix()` names each try's logs. The port, or 0 if no try came up (`master` then
/// holds the last try).
int start_listening(std::unique_ptr<Process>& master, const std::vector<std::string>& argv,
                    const std::function<std::filesystem::path()>& log_prefix);

/// An executable of the build tree: BUILD/<subdir>/<name>, BUILD holding this test's folder.
std::string binary(const char* subdir, const char* name);

/// Whole file as text ("" if it does not exist).
std::string read_text(const std::filesystem::path& path);

/// Occurrences of `needle` in `haystack`.
size_t count_of(const std::string& haystack, const std::string& needle);

/// Prints a line of a test's story, printf-style, with the seconds since `start`.
template <class... A>
void print_note(std::chrono::steady_clock::time_point start, const char* format, A... args) {
  std::printf("  [%6.2f s] ", std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  if constexpr (sizeof...(A) == 0)
    std::fputs(format, stdout);  // a format without arguments is printed as it is
  else
    std::printf(format, args...);
  std::printf("\n");
  std::fflush(stdout);
}

/// Prints the last 3000 bytes of a process's log to stderr under a "---- name ----" line (a failed
/// test's evidence).
void print_log_tail(const std::string& name, const std::string& text);

}  // namespace epr::testing
