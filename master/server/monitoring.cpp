#include "master/server/monitoring.h"

#include <fmt/format.h>
#include <httplib.h>

#include <atomic>
#include <nlohmann/json.hpp>
#include <set>
#include <stdexcept>
#include <string_view>
#include <thread>

#include "common/address.h"
#include "common/check.h"
#include "common/log.h"
#include "common/thread_name.h"
#include "master/server/job_manager.h"
#include "master/server/monitoring_format.h"
#include "master/server/previews.h"
#include "wire/rpc/auth_interceptor.h"
#include "wire/rpc/token.h"
#include "wire/sha256.h"

namespace epr {

/// master/server/dashboard.html, compiled in by CMake (embed_text.cmake).
std::string_view dashboard_html();

namespace {

using json = nlohmann::json;

void send_json(httplib::Response& res, int status, const json& body) {
  res.status = status;
  res.set_header("Cache-Control", "no-store");
  res.set_content(body.dump(), "application/json");
}

void send_error(httplib::Response& res, int status, const std::string& error, const std::string& reason = {}) {
  json body{{"error", error}};
  if (!reason.empty()) body["reason"] = reason;
  send_json(res, status, body);
}

json workers_json(const JobManager& jobs) {
  json out = json::array();
  for (const auto& w : jobs.workers()) out.push_back(to_json(w));
  return out;
}

// The session cookie's name and value for `token`: a digest, so a cookie taken from a browser
// opens the monitoring pages only, never the gRPC services.
constexpr std::string_view kCookie = "epr_session";
std::string session_of(const std::string& token) {
  Sha256 h;
  h.update(std::string("eprfarm monitoring session\n"));
  h.update(token);
  return h.hex();
}

// The value of cookie `name` in a Cookie header ("a=1; b=2"); empty if absent.
std::string cookie_value(const std::string& header, std::string_view name) {
  size_t at = 0;
  while (at < header.size()) {
    size_t end = header.find(';', at);
    if (end == std::string::npos) end = header.size();
    std::string_view pair(header.data() + at, end - at);
    while (!pair.empty() && pair.front() == ' ') pair.remove_prefix(1);
    if (pair.size() > name.size() && pair.substr(0, name.size()) == name && pair[name.size()] == '=')
      return std::string(pair.substr(name.size() + 1));
    at = end + 1;
  }
  return {};
}

// GET / without a token: a form that sends the token to /login, which sets the session cookie.
constexpr std::string_view kLoginPage = R"(<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>eprfarm: sign in</title>
<style>body{font:15px system-ui,sans-serif;background:#f4f5f7;display:flex;justify-content:center;padding-top:15vh}
form{background:#fff;border:1px solid #e3e6ec;border-radius:8px;padding:20px 24px;width:340px}
input{width:100%;margin:8px 0 12px;padding:6px;font:inherit}#error{color:#d64545;min-height:1.4em}</style></head>
<body><form id="login"><b>eprfarm monitoring</b><p>This master requires its bearer token.</p>
<label>Token<input id="token" type="password" autocomplete="current-password" autofocus></label>
<button type="submit">Sign in</button><div id="error"></div></form>
<script>
document.getElementById("login").onsubmit = async (ev) => {
  ev.preventDefault();
  const error = document.getElementById("error");
  try {
    const r = await fetch("login", { cache: "no-store",
      headers: { Authorization: "Bearer " + document.getElementById("token").value.trim() } });
    if (r.ok) { location.reload(); return; }
    error.textContent = r.status === 401 ? "That token is not valid for this master." : "HTTP " + r.status;
  } catch (e) { error.textContent = "The token must be printable ASCII without spaces."; }
};
</script></body></html>
)";

// A short strong validator of the image bytes (FNV-1a, 64 bit).
std::string etag_of(const std::vector<unsigned char>& bytes) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char b : bytes) h = (h ^ b) * 1099511628211ull;
  return fmt::format("\"{:016x}\"", h);
}

}  // namespace

std::optional<std::pair<std::string, int>> parse_host_port(const std::string& address, std::string* why) {
  auto a = parse_address(address, {.port_zero = true, .empty_host = true}, why);
  if (!a) return std::nullopt;
  return std::make_pair(a->host.empty() ? std::string("0.0.0.0") : a->host, a->port);
}

struct MonitoringServer::Impl {
  JobManager& jobs;
  MonitoringOptions options;
  std::unique_ptr<httplib::Server> server;
  httplib::Server& http;
  std::thread thread;
  std::string host;
  int port = 0;
  FarmTotalsTracker totals;
  std::atomic<bool> listen_returned{false};
  Mutex stop_mu;  // also makes a second stop() wait until the first has joined the thread
  bool stopped EPR_GUARDED_BY(stop_mu) = false;

  // With a token: the bearer check, and the same check of the session cookie against its digest.
  std::optional<rpc::BearerTokenCheck> bearer, session;
  std::string session_cookie;

  Impl(JobManager& j, MonitoringOptions o)
      : jobs(j), options(std::move(o)), server(make_http_server(options.limits)), http(*server) {}
  void routes();
  bool authorized(const httplib::Request& req) const;
  void unauthorized(const httplib::Request& req, httplib::Response& res) const;
  void image(const httplib::Request& req, httplib::Response& res);
};

void MonitoringServer::Impl::routes() {
  http.set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
    http_request_headers_received();
    if (req.method != "GET" && req.method != "HEAD") {
      res.set_header("Allow", "GET, HEAD");
      send_error(res, 405, fmt::format("the monitoring endpoint is read-only ({} is not allowed)", req.method));
      return httplib::Server::HandlerResponse::Handled;
    }
    if (bearer && req.path != "/healthz" && req.path != "/readyz" && !authorized(req)) {
      unauthorized(req, res);
      return httplib::Server::HandlerResponse::Handled;
    }
    return httplib::Server::HandlerResponse::Unhandled;
  });
  http.set_error_handler([](const httplib::Request&, httplib::Response& res) {
    if (res.body.empty())
      send_error(res, res.status, res.status == 404 ? "not found" : fmt::format("HTTP {}", res.status));
  });
  http.set_exception_handler([](const httplib::Request& req, httplib::Response& res, std::exception_ptr ep) {
    std::string what = "unknown exception";
    try {
      std::rethrow_exception(ep);
    } catch (const std::exception& e) {
      what = e.what();
    } catch (...) {
    }
    logger("master")->error("monitoring: {} {}: {}", req.method, req.path, what);
    send_error(res, 500, "internal error");
  });

  http.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_header("Cache-Control", "no-cache");
    res.set_content(std::string(dashboard_html()), "text/html; charset=utf-8");
  });
  http.Get("/login", [this](const httplib::Request&, httplib::Response& res) {
    res.status = 204;
    res.set_header("Cache-Control", "no-store");
    // A session cookie (no Max-Age): it ends with the browser session.
    if (bearer)
      res.set_header("Set-Cookie", fmt::format("{}={}; Path=/; HttpOnly; SameSite=Strict", kCookie, session_cookie));
  });
  http.Get("/healthz", [](const httplib::Request&, httplib::Response& res) {
    send_json(res, 200, {{"status", "ok"}});
  });
  http.Get("/readyz", [this](const httplib::Request&, httplib::Response& res) {
    const bool gl = jobs.gl_ready();
    const bool ready = gl || options.cpu_reprojector;
    json body{{"ready", ready}, {"osmesa", gl}, {"reprojector", gl ? "gl" : "cpu"}};
    if (!ready) body["reason"] = "the OSMesa context is not up (yet)";
    send_json(res, ready ? 200 : 503, body);
  });
  http.Get("/api/v1/jobs", [this](const httplib::Request&, httplib::Response& res) {
    json list = json::array();
    for (const auto& s : jobs.list()) list.push_back(to_json(s));
    send_json(res, 200, {{"jobs", std::move(list)}, {"workers", workers_json(jobs)}, {"osmesa", jobs.gl_ready()}});
  });
  http.Get("/api/v1/workers", [this](const httplib::Request&, httplib::Response& res) {
    send_json(res, 200, {{"workers", workers_json(jobs)}});
  });
  http.Get(R"(/api/v1/jobs/([^/]+))", [this](const httplib::Request& req, httplib::Response& res) {
    const std::string id = req.matches[1];
    auto s = jobs.get(id);
    if (!s) return send_error(res, 404, fmt::format("no job '{}'", id), "no_job");
    json body = to_json(*s);
    body["workers"] = workers_json(jobs);
    send_json(res, 200, body);
  });
  http.Get(R"(/api/v1/jobs/([^/]+)/image\.png)",
           [this](const httplib::Request& req, httplib::Response& res) { image(req, res); });
  http.Get("/metrics", [this](const httplib::Request&, httplib::Response& res) {
    MetricsInput in;
    in.jobs = jobs.list();
    in.workers = jobs.workers();
    in.histograms = jobs.histograms();
    in.gl_ready = jobs.gl_ready();
    in.tiles_waiting = jobs.tiles_waiting();
    in.totals = totals.update(in.jobs);
    res.set_header("Cache-Control", "no-store");
    res.set_content(prometheus_text(in), "text/plain; version=0.0.4; charset=utf-8");
  });
}

bool MonitoringServer::Impl::authorized(const httplib::Request& req) const {
  using Metadata = std::multimap<grpc::string_ref, grpc::string_ref>;
  if (req.has_header("Authorization")) {
    const std::string value = req.get_header_value("Authorization");
    return bearer->check(Metadata{{"authorization", value}}).ok();
  }
  const std::string cookie = cookie_value(req.get_header_value("Cookie"), kCookie);
  if (cookie.empty()) return false;
  const std::string value = "Bearer " + cookie;
  return session->check(Metadata{{"authorization", value}}).ok();
}

void MonitoringServer::Impl::unauthorized(const httplib::Request& req, httplib::Response& res) const {
  const bool sent = req.has_header("Authorization") || !cookie_value(req.get_header_value("Cookie"), kCookie).empty();
  res.set_header("WWW-Authenticate",
                 sent ? R"(Bearer realm="eprfarm", error="invalid_token")" : R"(Bearer realm="eprfarm")");
  if (req.path == "/") {
    res.status = 401;
    res.set_header("Cache-Control", "no-store");
    res.set_content(std::string(kLoginPage), "text/html; charset=utf-8");
    return;
  }
  send_error(res, 401,
             sent ? "the bearer token is not valid for this master"
                  : "this master requires a bearer token (Authorization: Bearer TOKEN)",
             "unauthorized");
}

void MonitoringServer::Impl::image(const httplib::Request& req, httplib::Response& res) {
  const std::string id = req.matches[1];
  const std::string layer = req.has_param("layer") ? req.get_param_value("layer") : "combined";
  if (!is_preview_layer(layer))
    return send_error(res, 400, fmt::format("unknown layer '{}' (combined, pathtrace, reprojection or samples)", layer),
                      "bad_layer");
  int max_side = kPreviewMaxSide;
  if (req.has_param("max")) {
    const auto bound = parse_preview_bound(req.get_param_value("max"));
    if (!bound)
      return send_error(res, 400,
                        fmt::format("max must be a positive integer (the preview's longest side, {} .. {} pixels)",
                                    kPreviewMinBound, kPreviewMaxBound),
                        "bad_max");
    max_side = *bound;
  }
  auto s = jobs.get(id);
  if (!s) return send_error(res, 404, fmt::format("no job '{}'", id), "no_job");
  auto png = jobs.preview_png(id, preview_key(layer, max_side));
  if (!png) {
    const bool reprojects = s->options.mode != RenderMode::kPathTrace;
    const bool pending = reprojects || layer == "combined" || layer == "pathtrace";
    if (pending)
      return send_error(
          res, 404,
          fmt::format(
              "job {} has no preview yet (its first round has not closed, or its image copy is still being taken)", id),
          "pending");
    return send_error(res, 404, fmt::format("job {} does not reproject: it has no '{}' layer", id, layer),
                      "layer_unavailable");
  }
  const std::string etag = etag_of(*png);
  res.set_header("ETag", etag);
  res.set_header("Cache-Control", "no-cache");
  // The image's own size, which a downscaled preview is not.
  res.set_header("X-Image-Size", fmt::format("{}x{}", s->options.width, s->options.height));
  if (req.get_header_value("If-None-Match") == etag) {
    res.status = 304;
    return;
  }
  res.set_content(reinterpret_cast<const char*>(png->data()), png->size(), "image/png");
}

MonitoringServer::MonitoringServer(JobManager& jobs, MonitoringOptions options)
    : impl_(std::make_unique<Impl>(jobs, std::move(options))) {
  std::string why;
  auto hp = parse_host_port(impl_->options.listen, &why);
  if (!hp) throw std::runtime_error(fmt::format("monitoring address '{}': {}", impl_->options.listen, why));
  impl_->host = hp->first;
  if (!impl_->options.token.empty()) {
    if (!rpc::is_valid_token(impl_->options.token))
      throw std::runtime_error("the monitoring token must be printable ASCII without spaces");
    impl_->bearer.emplace(impl_->options.token);
    impl_->session_cookie = session_of(impl_->options.token);
    impl_->session.emplace(impl_->session_cookie);
  }
  impl_->http.set_payload_max_length(64 << 10);  // nothing is uploaded here
  // cpp-httplib's default sets SO_REUSEPORT, which lets a second master bind the same port and take
  // half of the requests; SO_REUSEADDR alone allows a quick restart but refuses a port in use.
  impl_->http.set_socket_options([](socket_t sock) {
    int yes = 1;
    setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
  });
  impl_->routes();
  impl_->port = bind_http_server(impl_->http, impl_->host, hp->second);
  if (impl_->port <= 0)
    throw std::runtime_error(
        fmt::format("cannot serve HTTP on {} (address in use or invalid?)", impl_->options.listen));
  impl_->thread = std::thread([impl = impl_.get()] {
    set_thread_name("epr-http");
    if (!impl->http.listen_after_bind()) logger("master")->error("monitoring: the HTTP listener stopped with an error");
    impl->listen_returned = true;
  });
  // stop() only interrupts a server that is running: wait until it is, so stop() cannot be lost.
  while (!impl_->http.is_running() && !impl_->listen_returned)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  logger("master")->info("monitoring on {}", url());
}

MonitoringServer::~MonitoringServer() { stop(); }

int MonitoringServer::port() const { return impl_->port; }

std::string MonitoringServer::url() const {
  std::string host = impl_->host;
  if (host == "0.0.0.0" || host == "::" || host.empty()) host = "127.0.0.1";
  if (host.find(':') != std::string::npos) host = "[" + host + "]";
  return fmt::format("http://{}:{}/", host, impl_->port);
}

void MonitoringServer::stop() {
  MutexLock lock(impl_->stop_mu);
  if (impl_->stopped) return;
  impl_->stopped = true;
  impl_->http.stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

}  // namespace epr
