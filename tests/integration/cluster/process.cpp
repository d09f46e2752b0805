#include "process.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <regex>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace epr::testing {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

Process::Process(std::vector<std::string> argv, const fs::path& log_prefix, const ProcessOptions& options)
    : name_(fs::path(argv.at(0)).filename().string()),
      out_path_(log_prefix.string() + ".out"),
      err_path_(log_prefix.string() + ".err") {
  if (::access(argv[0].c_str(), X_OK) != 0)
    throw std::runtime_error("cannot run " + argv[0] + ": " + std::strerror(errno));
  // Everything the child needs is prepared before fork: after it, only async-signal-safe calls.
  std::vector<char*> args;
  for (auto& a : argv) args.push_back(a.data());
  args.push_back(nullptr);
  std::vector<std::string> env_strings;
  for (char** e = environ; *e; ++e) {
    const std::string entry = *e;
    const std::string name = entry.substr(0, entry.find('='));
    bool replaced = false;
    for (const auto& o : options.env) replaced |= o.substr(0, o.find('=')) == name;
    if (!replaced) env_strings.push_back(entry);
  }
  env_strings.insert(env_strings.end(), options.env.begin(), options.env.end());
  std::vector<char*> env;
  for (auto& e : env_strings) env.push_back(e.data());
  env.push_back(nullptr);
  const rlim_t file_size_limit = rlim_t(options.file_size_limit);
  const pid_t parent = ::getpid();
  pid_ = ::fork();
  if (pid_ < 0) throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
  if (pid_ == 0) {
    // Killed with the test process, even if that one crashes or is killed by ctest's timeout.
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(127);
    const int in = ::open("/dev/null", O_RDONLY);
    const int out = ::open(out_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int err = ::open(err_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (in < 0 || out < 0 || err < 0) ::_exit(127);
    ::dup2(in, STDIN_FILENO);
    ::dup2(out, STDOUT_FILENO);
    ::dup2(err, STDERR_FILENO);
    if (file_size_limit > 0) {
      struct sigaction ignore {};
      ignore.sa_handler = SIG_IGN;
      const struct rlimit limit { file_size_limit, file_size_limit };
      if (::sigaction(SIGXFSZ, &ignore, nullptr) != 0 || ::setrlimit(RLIMIT_FSIZE, &limit) != 0) ::_exit(127);
    }
    ::execve(args[0], args.data(), env.data());
    ::_exit(127);
  }
}

Process::~Process() {
  if (pid_ > 0 && !exit_code_) stop(Millis(3000));
}

bool Process::reap(bool block) {
  if (pid_ <= 0 || exit_code_) return true;
  int status = 0;
  pid_t r;
  do {
    r = waitpid(pid_, &status, block ? 0 : WNOHANG);
  } while (r < 0 && errno == EINTR);
  if (r == 0) return false;
  if (r < 0) {  // not our child any more (should not happen): treat as gone
    exit_code_ = -1;
    return true;
  }
  exit_code_ = WIFEXITED(status) ? WEXITSTATUS(status) : WIFSIGNALED(status) ? 128 + WTERMSIG(status) : -1;
  return true;
}

bool Process::running() { return !reap(false); }

std::optional<int> Process::wait_for(Millis timeout) {
  const auto end = Clock::now() + timeout;
  while (!reap(false)) {
    if (Clock::now() >= end) return std::nullopt;
    std::this_thread::sleep_for(Millis(10));
  }
  return exit_code_;
}

void Process::signal(int sig) {
  if (pid_ > 0 && !exit_code_) ::kill(pid_, sig);
}

int Process::stop(Millis grace) {
  signal(SIGCONT);  // in case a test stopped it
  signal(SIGTERM);
  if (!wait_for(grace)) {
    signal(SIGKILL);
    reap(true);
  }
  return *exit_code_;
}

std::string Process::out() const { return read_text(out_path_); }
std::string Process::err() const { return read_text(err_path_); }

RunResult run_process(std::vector<std::string> argv, const fs::path& log_prefix, Millis timeout) {
  const auto start = Clock::now();
  Process p(std::move(argv), log_prefix);
  RunResult r;
  if (auto code = p.wait_for(timeout)) {
    r.code = *code;
  } else {
    r.timed_out = true;
    r.code = p.stop(Millis(2000));
  }
  r.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  r.out = p.out();
  r.err = p.err();
  return r;
}

bool wait_until(const std::function<bool()>& done, Millis timeout) {
  const auto end = Clock::now() + timeout;
  for (;;) {
    if (done()) return true;
    if (Clock::now() >= end) return done();
    std::this_thread::sleep_for(Millis(20));
  }
}

int listening_port(Process& master, Millis timeout) {
  const std::regex listening("listening on port ([0-9]+)");
  int port = 0;
  wait_until(
      [&] {
        std::smatch m;
        const std::string err = master.err();
        if (std::regex_search(err, m, listening)) port = std::stoi(m[1]);
        return port != 0 || !master.running();
      },
      timeout);
  return port;
}

int start_listening(std::unique_ptr<Process>& master, const std::vector<std::string>& argv,
                    const std::function<fs::path()>& log_prefix) {
  for (int attempt = 0; attempt < 20; ++attempt) {
    master = std::make_unique<Process>(argv, log_prefix());
    const int port = listening_port(*master, Millis(10000));
    if (port != 0 && master->running()) return port;
    std::this_thread::sleep_for(Millis(250));
  }
  return 0;
}

std::string binary(const char* subdir, const char* name) {
  return (fs::read_symlink("/proc/self/exe").parent_path().parent_path() / subdir / name).string();
}

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

size_t count_of(const std::string& haystack, const std::string& needle) {
  size_t n = 0;
  for (size_t p = haystack.find(needle); p != std::string::npos; p = haystack.find(needle, p + needle.size())) ++n;
  return n;
}

void print_log_tail(const std::string& name, const std::string& text) {
  const size_t from = text.size() > 3000 ? text.size() - 3000 : 0;
  std::fprintf(stderr, "---- %s (last %zu bytes) ----\n%s\n", name.c_str(), text.size() - from,
               text.substr(from).c_str());
}

}  // namespace epr::testing
