// The master's HTTP monitoring endpoint (DESIGN.md section 2): a read-only cpp-httplib server over
// the JobManager, on its own port beside gRPC.
//
//   GET /                                   the dashboard (master/server/dashboard.html, compiled in)
//   GET /healthz                            200 {"status":"ok"} while the process serves
//   GET /readyz                             200 when the reprojection back-end is up (the OSMesa context,
//                                           or the CPU reprojector when the master was told --reproject cpu);
//                                           503 while the OSMesa context is not (yet) up
//   GET /api/v1/jobs                        {"jobs":[job...], "workers":[worker...], "osmesa": bool}
//   GET /api/v1/jobs/{id}                   one job (monitoring_format.h) plus "workers"; 404 JSON if unknown
//   GET /api/v1/jobs/{id}/image.png?layer=  combined (default) | pathtrace | reprojection | samples: the
//                                           preview after the last round that refreshed it (sRGB PNG,
//                                           `samples` is the M' heat map), at most 1024 pixels on its
//                                           longest side (&max=N: 64 .. 8192, rounded down to a power of
//                                           two; 400 "bad_max" if not a positive integer), box-filtered by
//                                           a whole factor (previews.h); X-Image-Size: the image's WxH.
//                                           404 JSON {"error","reason"} when
//                                           the job is unknown ("no_job"), has no preview yet ("pending",
//                                           before its first round closes) or has no such layer
//                                           ("layer_unavailable": pt mode has no reprojection layers);
//                                           400 JSON for an unknown layer. ETag + If-None-Match -> 304.
//   GET /api/v1/workers                     {"workers":[...]}
//   GET /metrics                            Prometheus text format 0.0.4 (monitoring_format.h)
//
//   GET /login                              with a valid Authorization header: 204 and the session
//                                           cookie (below); the dashboard's login form calls it
//
// Any other method gets 405 {"error":...} with "Allow: GET, HEAD". Unknown paths get 404 JSON.
//
// With a token (MonitoringOptions::token, the master's --token-file), every path but /healthz and
// /readyz needs "Authorization: Bearer TOKEN" or the session cookie that /login sets (HttpOnly,
// SameSite=Strict, a digest of the token rather than the token); both are compared in constant time.
// Otherwise 401 with "WWW-Authenticate: Bearer": JSON, or for GET / a login page.
//
// Connections: master/server/http_server.h (a thread per connection up to a cap, header deadline,
// keep-alive limits); handlers only copy JobManager snapshots.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "master/server/http_server.h"

namespace epr {

class JobManager;

struct MonitoringOptions {
  std::string listen = "0.0.0.0:8080";  // HOST:PORT ("[::]:8080" for IPv6); port 0 picks a free port
  bool cpu_reprojector = false;         // the master forces the CPU reprojector: ready without OSMesa
  std::string token;                    // bearer token required on all but /healthz and /readyz; empty: open
  HttpLimits limits;                    // connections, deadlines, keep-alive
};

class MonitoringServer {
 public:
  /// Binds and starts serving; throws std::runtime_error if the address is malformed or cannot be bound,
  /// or the token is not one token (wire/rpc/token.h).
  MonitoringServer(JobManager& jobs, MonitoringOptions options);
  ~MonitoringServer();
  MonitoringServer(const MonitoringServer&) = delete;
  MonitoringServer& operator=(const MonitoringServer&) = delete;

  int port() const;
  /// "http://HOST:PORT/" as reachable from this host (a wildcard bind address becomes 127.0.0.1).
  std::string url() const;
  /// Stops serving and joins the listener thread. Idempotent.
  void stop();

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

/// Splits "HOST:PORT", "[V6]:PORT" or ":PORT" (host 0.0.0.0) by common/address.h's rules, port 0
/// allowed (a free one); nullopt if malformed, the reason in *why.
std::optional<std::pair<std::string, int>> parse_host_port(const std::string& address, std::string* why = nullptr);

}  // namespace epr
