#include "master/server/http_server.h"

#include <arpa/inet.h>
#include <httplib.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <optional>
#include <set>
#include <string>
#include <thread>

#include "common/check.h"
#include "common/thread_name.h"

namespace epr {
namespace {

using Clock = std::chrono::steady_clock;

Clock::duration seconds(double s) {
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
}

// Waits for `events` on `sock` until `until`; false on timeout, error or hang-up without data.
bool wait_for(int sock, short events, Clock::time_point until) {
  for (;;) {
    const auto left = std::chrono::ceil<std::chrono::milliseconds>(until - Clock::now()).count();
    if (left <= 0) return false;
    pollfd p{sock, events, 0};
    const int n = ::poll(&p, 1, int(std::min<long long>(left, 60'000)));
    if (n > 0) return (p.revents & (events | POLLHUP | POLLERR)) != 0;
    if (n < 0 && errno != EINTR) return false;
  }
}

void address_of(int sock, bool peer, std::string& ip, int& port) {
  sockaddr_storage a{};
  socklen_t len = sizeof a;
  const int r = peer ? ::getpeername(sock, reinterpret_cast<sockaddr*>(&a), &len)
                     : ::getsockname(sock, reinterpret_cast<sockaddr*>(&a), &len);
  if (r != 0) return;
  char text[INET6_ADDRSTRLEN] = {};
  if (a.ss_family == AF_INET) {
    const auto* v4 = reinterpret_cast<const sockaddr_in*>(&a);
    ::inet_ntop(AF_INET, &v4->sin_addr, text, sizeof text);
    port = ntohs(v4->sin_port);
  } else if (a.ss_family == AF_INET6) {
    const auto* v6 = reinterpret_cast<const sockaddr_in6*>(&a);
    ::inet_ntop(AF_INET6, &v6->sin6_addr, text, sizeof text);
    port = ntohs(v6->sin6_port);
  }
  ip = text;
}

// One connection's socket as cpp-httplib's Stream: buffered reads bounded by the io timeout and,
// until the request's headers are in, by the header deadline and byte limit.
class ConnectionStream final : public httplib::Stream {
 public:
  ConnectionStream(int sock, const HttpLimits& limits) : sock_(sock), limits_(limits) {}

  /// Waits up to idle_seconds for the first byte of the next request; starts its header deadline.
  bool next_request() {
    if (pos_ == len_ && !wait_for(sock_, POLLIN, Clock::now() + seconds(limits_.idle_seconds))) return false;
    header_deadline_ = Clock::now() + seconds(limits_.header_seconds);
    header_bytes_ = len_ - pos_;
    return true;
  }
  void headers_received() { header_deadline_.reset(); }
  /// A request's line and headers did not arrive in time or were too long: the connection is done.
  bool failed() const { return failed_; }

  bool is_readable() const override { return pos_ < len_ || wait_for(sock_, POLLIN, read_until()); }
  bool is_writable() const override { return wait_for(sock_, POLLOUT, Clock::now() + seconds(limits_.io_seconds)); }

  ssize_t read(char* ptr, size_t size) override {
    if (pos_ == len_) {
      if (!wait_for(sock_, POLLIN, read_until())) {
        failed_ = failed_ || header_deadline_.has_value();
        return -1;
      }
      const ssize_t n = ::recv(sock_, buf_, sizeof buf_, 0);
      if (n <= 0) return n;
      pos_ = 0;
      len_ = size_t(n);
      if (header_deadline_ && (header_bytes_ += len_) > limits_.max_header_bytes) {
        failed_ = true;
        return -1;
      }
    }
    const size_t n = std::min(size, len_ - pos_);
    std::memcpy(ptr, buf_ + pos_, n);
    pos_ += n;
    return ssize_t(n);
  }

  // The socket is blocking with SO_SNDTIMEO = io_seconds (set by cpp-httplib on accept).
  ssize_t write(const char* ptr, size_t size) override {
    if (!is_writable()) return -1;
    return ::send(sock_, ptr, size, MSG_NOSIGNAL);
  }

  void get_remote_ip_and_port(std::string& ip, int& port) const override { address_of(sock_, true, ip, port); }
  void get_local_ip_and_port(std::string& ip, int& port) const override { address_of(sock_, false, ip, port); }
  // cpp-httplib reads this only to refuse descriptors beyond select()'s FD_SETSIZE; this stream
  // polls, so any descriptor is fine.
  socket_t socket() const override { return 0; }

 private:
  Clock::time_point read_until() const {
    const auto io = Clock::now() + seconds(limits_.io_seconds);
    return header_deadline_ ? std::min(io, *header_deadline_) : io;
  }

  int sock_;
  const HttpLimits& limits_;
  char buf_[4096];
  size_t pos_ = 0, len_ = 0;
  std::optional<Clock::time_point> header_deadline_;
  size_t header_bytes_ = 0;
  bool failed_ = false;
};

// The connection being served on this thread (for http_request_headers_received).
thread_local ConnectionStream* t_stream = nullptr;
// Set on the accepting thread while it refuses a connection beyond the cap.
thread_local bool t_refuse = false;

// The open connections: the cap, and the sockets to wake when the server stops.
class Connections {
 public:
  explicit Connections(int max) : max_(max) {}

  bool admit() EPR_EXCLUDES(mu_) {
    MutexLock lock(mu_);
    if (stopping_ || threads_ >= max_) return false;
    ++threads_;
    return true;
  }
  void thread_done() EPR_EXCLUDES(mu_) {
    MutexLock lock(mu_);
    --threads_;
    cv_.notify_all();
  }
  bool add(int sock) EPR_EXCLUDES(mu_) {
    MutexLock lock(mu_);
    if (stopping_) return false;
    socks_.insert(sock);
    return true;
  }
  void remove(int sock) EPR_EXCLUDES(mu_) {
    MutexLock lock(mu_);
    socks_.erase(sock);
  }
  /// Refuses new connections, wakes the open ones (their reads end) and waits for their threads.
  void stop() EPR_EXCLUDES(mu_) {
    MutexLock lock(mu_);
    stopping_ = true;
    for (int s : socks_) ::shutdown(s, SHUT_RDWR);
    cv_.wait(lock, [&]() EPR_REQUIRES(mu_) { return threads_ == 0; });
  }

 private:
  const int max_;
  Mutex mu_;
  std::condition_variable_any cv_;
  bool stopping_ EPR_GUARDED_BY(mu_) = false;
  int threads_ EPR_GUARDED_BY(mu_) = 0;
  std::set<int> socks_ EPR_GUARDED_BY(mu_);
};

// cpp-httplib's accept loop hands each connection to this queue: a thread of its own, or (beyond
// the cap, or if no thread can be started) a refusal on the accepting thread.
class ThreadPerConnection final : public httplib::TaskQueue {
 public:
  explicit ThreadPerConnection(Connections& c) : connections_(c) {}

  void enqueue(std::function<void()> fn) override {
    if (connections_.admit()) {
      try {
        std::thread([c = &connections_, fn] {
          set_thread_name("epr-http");
          fn();
          c->thread_done();
        }).detach();
        return;
      } catch (const std::system_error&) {
        connections_.thread_done();
      }
    }
    t_refuse = true;
    fn();
    t_refuse = false;
  }
  void shutdown() override { connections_.stop(); }

 private:
  Connections& connections_;
};

class Server final : public httplib::Server {
 public:
  int bind(const std::string& host, int port) {
    const int bound = port == 0 ? bind_to_any_port(host) : (bind_to_port(host, port) ? port : -1);
    if (bound <= 0) return -1;
    // Listening again on a listening socket only changes its backlog.
    if (::listen(svr_sock_, SOMAXCONN) != 0) return -1;
    return bound;
  }

  explicit Server(const HttpLimits& limits) : limits_(limits), connections_(std::max(1, limits.max_connections)) {
    new_task_queue = [this] { return new ThreadPerConnection(connections_); };
    // cpp-httplib sets these on each accepted socket (SO_RCVTIMEO, SO_SNDTIMEO).
    const auto io_sec = time_t(limits.io_seconds);
    const auto io_usec = time_t((limits.io_seconds - double(io_sec)) * 1e6);
    set_read_timeout(io_sec, io_usec);
    set_write_timeout(io_sec, io_usec);
  }

 private:
  // Called by cpp-httplib's accept loop (through the task queue) for each accepted socket.
  bool process_and_close_socket(socket_t sock) override {
    if (t_refuse) {
      refuse(sock);
      return false;
    }
    if (connections_.add(sock)) {
      ConnectionStream strm(sock, limits_);
      t_stream = &strm;
      for (int n = 0; n < limits_.max_requests && strm.next_request(); ++n) {
        bool closed = false;
        if (!process_request(strm, n + 1 == limits_.max_requests, closed, nullptr) || closed || strm.failed()) break;
      }
      t_stream = nullptr;
      connections_.remove(sock);
    }
    ::shutdown(sock, SHUT_RDWR);
    ::close(sock);
    return true;
  }

  // A connection beyond the cap: whatever it already sent is read (so that closing does not reset
  // the answer away), then a 503 without waiting, and it is closed.
  static void refuse(int sock) {
    char drain[4096];
    for (int i = 0; i < 16 && ::recv(sock, drain, sizeof drain, MSG_DONTWAIT) > 0; ++i) {
    }
    static const char kBusy[] =
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\nRetry-After: 1\r\n"
        "Connection: close\r\nContent-Length: 42\r\n\r\n{\"error\":\"too many open HTTP connections\"}";
    [[maybe_unused]] const ssize_t sent = ::send(sock, kBusy, sizeof kBusy - 1, MSG_DONTWAIT | MSG_NOSIGNAL);
    ::shutdown(sock, SHUT_RDWR);
    ::close(sock);
  }

  HttpLimits limits_;
  Connections connections_;
};

}  // namespace

std::unique_ptr<httplib::Server> make_http_server(const HttpLimits& limits) { return std::make_unique<Server>(limits); }

int bind_http_server(httplib::Server& server, const std::string& host, int port) {
  return static_cast<Server&>(server).bind(host, port);
}

void http_request_headers_received() {
  if (t_stream) t_stream->headers_received();
}

}  // namespace epr
