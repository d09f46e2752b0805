// The monitoring endpoint under slow and idle clients, with real sockets on loopback: /healthz
// answers within a second while 100 idle connections and 100 slow-header connections (one header
// line every 1.5 s) are open, the API still serves, and the server closes slow connections at the
// header deadline, idle ones at the keep-alive timeout, connections beyond the cap at once (503), and
// a connection after its last keep-alive request.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <algorithm>
#include <condition_variable>
#include <mutex>

#include "master/server/monitoring.h"
#include "monitoring_helpers.h"

namespace epr::monitoring_test {
namespace {

int connect_to(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(uint16_t(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (fd < 0 || ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    ADD_FAILURE() << "connect: " << std::strerror(errno);
    if (fd >= 0) ::close(fd);
    return -1;
  }
  return fd;
}

bool send_text(int fd, const std::string& s) {
  return ::send(fd, s.data(), s.size(), MSG_NOSIGNAL) == ssize_t(s.size());
}

/// Reads what the server sent so far (into `got`); true once it has closed the connection.
bool closed_by_server(int fd, std::string* got = nullptr) {
  char buf[4096];
  for (;;) {
    const ssize_t n = ::recv(fd, buf, sizeof buf, MSG_DONTWAIT);
    if (n > 0) {
      if (got) got->append(buf, size_t(n));
      continue;
    }
    return n == 0 || (errno != EAGAIN && errno != EWOULDBLOCK);
  }
}

/// Seconds that /healthz takes on a new connection; 99 if it does not answer 200 within 3 s.
double probe_healthz(int port) {
  httplib::Client c("127.0.0.1", port);
  c.set_connection_timeout(3, 0);
  c.set_read_timeout(3, 0);
  const auto t0 = Clock::now();
  auto r = c.Get("/healthz");
  return r && r->status == 200 ? seconds_since(t0) : 99.0;
}

/// Connections that send a request line, then one header line every 1.5 s, never the blank line.
class SlowSenders {
 public:
  SlowSenders(int port, int n) {
    for (int i = 0; i < n; ++i) {
      fds_.push_back(connect_to(port));
      send_text(fds_.back(), "GET /healthz HTTP/1.1\r\n");
      opened_.push_back(Clock::now());
    }
    thread_ = std::thread([this] {
      std::unique_lock<std::mutex> lock(mu_);
      for (int line = 0; !cv_.wait_for(lock, std::chrono::milliseconds(1500), [&] { return stop_; }); ++line) {
        for (int fd : fds_) send_text(fd, "X-Slow-" + std::to_string(line) + ": 1\r\n");
        ++rounds_;
      }
    });
  }
  ~SlowSenders() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
    for (int fd : fds_) ::close(fd);
  }
  int rounds() {
    std::lock_guard<std::mutex> lock(mu_);
    return rounds_;
  }
  const std::vector<int>& fds() const { return fds_; }
  Clock::time_point opened(size_t i) const { return opened_[i]; }

 private:
  std::vector<int> fds_;
  std::vector<Clock::time_point> opened_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  int rounds_ = 0;
  std::thread thread_;
};

struct IdleConnections {
  IdleConnections(int port, int n) {
    for (int i = 0; i < n; ++i) fds.push_back(connect_to(port));
  }
  ~IdleConnections() {
    for (int fd : fds) ::close(fd);
  }
  std::vector<int> fds;
};

int count_closed(const std::vector<int>& fds) {
  return int(std::count_if(fds.begin(), fds.end(), [](int fd) { return closed_by_server(fd); }));
}

// A monitoring server on a free loopback port with these connection limits.
MonitoringOptions on_loopback(const HttpLimits& limits) {
  MonitoringOptions o;
  o.listen = "127.0.0.1:0";
  o.limits = limits;
  return o;
}

TEST(MonitoringConnections, HealthzAnswersWithinASecondWhile200SlowAndIdleConnectionsAreOpen) {
  auto master = start_master();
  HttpLimits limits;
  limits.idle_seconds = 120;   // the idle connections stay for the whole test
  limits.header_seconds = 12;  // the slow ones until after the probes
  MonitoringServer server(master->jobs(), on_loopback(limits));

  IdleConnections idle(server.port(), 100);
  SlowSenders slow(server.port(), 100);
  // Two header lines on every slow connection: each holds a request open that is still arriving.
  ASSERT_TRUE(wait_for([&] { return slow.rounds() >= 2; }, 30));

  std::vector<double> probes;
  for (int i = 0; i < 7; ++i) probes.push_back(probe_healthz(server.port()));
  std::sort(probes.begin(), probes.end());
  std::printf("/healthz with 100 idle and 100 slow connections open: median %.4f s, slowest %.4f s\n",
              probes[probes.size() / 2], probes.back());
  EXPECT_LT(probes[probes.size() / 2], 0.9) << "median of 7 /healthz probes; slowest " << probes.back() << " s";
  EXPECT_LT(probes.back(), 3.0) << "a /healthz probe went unanswered";

  // The API serves too, and every connection of the attack was still open during the probes.
  httplib::Client c("127.0.0.1", server.port());
  c.set_read_timeout(5, 0);
  const json jobs = get_json(c, "/api/v1/jobs");
  EXPECT_TRUE(jobs.contains("jobs"));
  auto metrics = c.Get("/metrics");
  ASSERT_TRUE(metrics);
  EXPECT_EQ(metrics->status, 200);
  EXPECT_EQ(count_closed(idle.fds), 0);
  std::string early;
  int slow_closed = 0;
  for (int fd : slow.fds()) slow_closed += closed_by_server(fd, &early) ? 1 : 0;
  EXPECT_EQ(slow_closed, 0) << early.substr(0, 600);

  // The slow connections end at the header deadline (12 s from their first byte), not before, and
  // are answered 400 or just closed; the idle ones stay (their idle timeout is longer).
  std::vector<double> closed_after(slow.fds().size(), -1);
  std::vector<std::string> answers(slow.fds().size());
  wait_for(
      [&] {
        for (size_t i = 0; i < slow.fds().size(); ++i)
          if (closed_after[i] < 0 && closed_by_server(slow.fds()[i], &answers[i]))
            closed_after[i] = seconds_since(slow.opened(i));
        return std::none_of(closed_after.begin(), closed_after.end(), [](double t) { return t < 0; });
      },
      40);
  for (size_t i = 0; i < closed_after.size(); ++i) {
    SCOPED_TRACE(i);
    EXPECT_GE(closed_after[i], 11.5) << answers[i];
    EXPECT_LT(closed_after[i], 30.0);
  }
  EXPECT_EQ(count_closed(idle.fds), 0);
  EXPECT_LT(probe_healthz(server.port()), 3.0);
  server.stop();
  master->shutdown();
}

TEST(MonitoringConnections, TheMastersDefaultsCloseIdleAndSlowConnections) {
  auto master = start_master();
  const HttpLimits defaults;
  const int port = master->http_port();
  const auto t0 = Clock::now();
  IdleConnections idle(port, 1);
  SlowSenders slow(port, 1);
  double idle_closed = -1, slow_closed = -1;
  wait_for(
      [&] {
        if (idle_closed < 0 && closed_by_server(idle.fds[0])) idle_closed = seconds_since(t0);
        if (slow_closed < 0 && closed_by_server(slow.fds()[0])) slow_closed = seconds_since(t0);
        return idle_closed >= 0 && slow_closed >= 0;
      },
      60);
  EXPECT_GE(idle_closed, defaults.idle_seconds - 0.5);
  EXPECT_LT(idle_closed, defaults.idle_seconds + 10);
  EXPECT_GE(slow_closed, defaults.header_seconds - 0.5);
  EXPECT_LT(slow_closed, defaults.header_seconds + 10);
  EXPECT_GE(slow.rounds(), 4) << "the slow connection kept sending until the deadline";
  master->shutdown();
}

TEST(MonitoringConnections, ConnectionsBeyondTheCapAreAnswered503AndClosed) {
  auto master = start_master();
  HttpLimits limits;
  limits.max_connections = 4;
  limits.idle_seconds = 120;
  MonitoringServer server(master->jobs(), on_loopback(limits));
  auto held = std::make_unique<IdleConnections>(server.port(), 4);
  // Each held connection has its thread once it answers a request (it then waits for the next one).
  for (int fd : held->fds) {
    ASSERT_TRUE(send_text(fd, "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n"));
    std::string got;
    ASSERT_TRUE(wait_for([&] { return closed_by_server(fd, &got) || got.find("\"ok\"") != std::string::npos; }, 30));
    EXPECT_NE(got.find("HTTP/1.1 200"), std::string::npos) << got;
  }
  const int extra = connect_to(server.port());
  send_text(extra, "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n");
  std::string got;
  ASSERT_TRUE(wait_for([&] { return closed_by_server(extra, &got); }, 30)) << "the fifth connection was kept";
  EXPECT_EQ(got.rfind("HTTP/1.1 503", 0), 0u) << got;
  EXPECT_NE(got.find("too many open HTTP connections"), std::string::npos) << got;
  ::close(extra);
  // Once the held connections go, new ones are served again.
  held.reset();
  EXPECT_TRUE(wait_for([&] { return probe_healthz(server.port()) < 3.0; }, 30));
  server.stop();
  master->shutdown();
}

TEST(MonitoringConnections, KeepAliveEndsAfterMaxRequests) {
  auto master = start_master();
  HttpLimits limits;
  limits.max_requests = 3;
  MonitoringServer server(master->jobs(), on_loopback(limits));
  const int fd = connect_to(server.port());
  std::string got;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(send_text(fd, "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n"));
    const size_t answers = size_t(i) + 1;
    ASSERT_TRUE(wait_for(
        [&] {
          const bool closed = closed_by_server(fd, &got);
          size_t n = 0;
          for (size_t at = got.find("\"ok\""); at != std::string::npos; at = got.find("\"ok\"", at + 1)) ++n;
          return n >= answers || closed;
        },
        30));
  }
  EXPECT_TRUE(wait_for([&] { return closed_by_server(fd, &got); }, 30)) << "kept open after its third request";
  EXPECT_NE(got.find("Connection: close"), std::string::npos) << got;
  size_t answers = 0;
  for (size_t at = got.find("HTTP/1.1 200"); at != std::string::npos; at = got.find("HTTP/1.1 200", at + 1)) ++answers;
  EXPECT_EQ(answers, 3u);
  ::close(fd);
  server.stop();
  master->shutdown();
}

}  // namespace
}  // namespace epr::monitoring_test
