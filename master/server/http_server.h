// The monitoring endpoint's HTTP server: cpp-httplib's request parsing and routing with a connection
// model of its own, so that slow or idle clients cannot starve the others (/healthz included).
//
// cpp-httplib 0.11.4 serves each connection on a fixed thread pool and its read timeout applies to
// each recv, so four clients sending one header line every 1.5 s, or forty idle ones, held every
// thread and nothing else was answered. Here:
//   - each accepted connection runs on its own thread, up to HttpLimits::max_connections; a
//     connection beyond that is answered 503 and closed on the accepting thread at once;
//   - a request's line and headers must arrive within header_seconds of its first byte, and hold at
//     most max_header_bytes, else the connection is closed;
//   - a connection waits at most idle_seconds for its next request, and serves at most max_requests;
//   - every other recv and send waits at most io_seconds.
// An event-driven server (libmicrohttpd) was the alternative; this keeps cpp-httplib's routes and
// costs one mostly idle thread per open connection, which the cap bounds (docs/MONITORING.md).
#pragma once

#include <cstddef>
#include <memory>
#include <string>

namespace httplib {
class Server;
}

namespace epr {

struct HttpLimits {
  int max_connections = 512;           // connections served at once
  double header_seconds = 10;          // to receive a request's line and headers, from its first byte
  size_t max_header_bytes = 64 << 10;  // request line plus headers
  double idle_seconds = 5;             // keep-alive: wait for the next request on a connection
  int max_requests = 100;              // keep-alive: requests per connection
  double io_seconds = 5;               // each recv/send otherwise (the body, the response)
};

/// A cpp-httplib server with the connection model above.
std::unique_ptr<httplib::Server> make_http_server(const HttpLimits& limits);

/// Binds `server` (made by make_http_server) to HOST:PORT, port 0 a free one, with a listen backlog of
/// SOMAXCONN: cpp-httplib listens with 5, and connections beyond it wait for SYN retransmits (1 s and
/// more) while the accepting thread is busy. Returns the port, or -1 if it cannot bind.
int bind_http_server(httplib::Server& server, const std::string& host, int port);

/// To be called first by the server's pre-routing handler: the request on this thread has its line
/// and headers in, so its header deadline ends. (A no-op on any other thread.)
void http_request_headers_received();

}  // namespace epr
