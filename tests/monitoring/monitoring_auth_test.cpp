// The monitoring endpoint of a master with a bearer token, over real HTTP on loopback: every route but
// /healthz and /readyz answers 401 (JSON, WWW-Authenticate: Bearer) without the token or with a wrong
// one, and 200 with it; the login route sets a session cookie that opens the same routes; GET /
// without a token is the login page. Without a token everything stays open.
#include <gtest/gtest.h>

#include "monitoring_helpers.h"

namespace epr::monitoring_test {
namespace {

const std::string kToken = "s3cret-Token_for.tests";

class MonitoringAuthTest : public ::testing::Test {
 protected:
  void SetUp() override {
    master_ = start_master("cpu", kToken);
    JobClientOptions co;
    co.token = kToken;
    client_ = std::make_unique<JobClient>(master_->local_target(), co);
    // One job with a closed round, so that its preview exists and every route has a 200 to give.
    id_ = client_->submit(small_job(4));
    ManualWorker worker(master_->local_target(), kToken);
    ASSERT_TRUE(wait_for(
        [&] {
          worker.work_available();  // none until the master has started the job
          return master_->jobs().preview_png(id_, "combined").has_value();
        },
        60));
  }
  void TearDown() override { master_->shutdown(); }

  std::vector<std::string> protected_paths() const {
    return {"/",
            "/api/v1/jobs",
            "/api/v1/workers",
            "/api/v1/jobs/" + id_,
            "/api/v1/jobs/" + id_ + "/image.png",
            "/api/v1/jobs/" + id_ + "/image.png?layer=samples",
            "/metrics",
            "/login"};
  }

  std::unique_ptr<MasterServer> master_;
  std::unique_ptr<JobClient> client_;
  std::string id_;
};

TEST_F(MonitoringAuthTest, EveryRouteButTheProbesNeedsTheToken) {
  auto http = http_client(*master_);
  const std::vector<std::pair<std::string, httplib::Headers>> refused = {
      {"no token", {}},
      {"wrong token", {{"Authorization", "Bearer " + kToken + "x"}}},
      {"a prefix of the token", {{"Authorization", "Bearer " + kToken.substr(0, 5)}}},
      {"not a bearer", {{"Authorization", "Basic " + kToken}}},
      {"no space after the scheme", {{"Authorization", "Bearer" + kToken}}},
      {"the scheme alone", {{"Authorization", "Bearer "}}},
      {"the token without a scheme", {{"Authorization", kToken}}},
      {"the token as the cookie", {{"Cookie", "epr_session=" + kToken}}},
  };
  for (const std::string& path : protected_paths()) {
    for (const auto& [what, headers] : refused) {
      SCOPED_TRACE(path + ", " + what);
      auto r = http.Get(path.c_str(), headers);
      ASSERT_TRUE(r);
      EXPECT_EQ(r->status, 401);
      EXPECT_EQ(r->get_header_value("WWW-Authenticate").rfind("Bearer realm=\"eprfarm\"", 0), 0u)
          << r->get_header_value("WWW-Authenticate");
      EXPECT_TRUE(r->get_header_value("Set-Cookie").empty());
      // Nothing of the farm leaks: no job id, no PNG, no metrics.
      EXPECT_EQ(r->body.find(id_), std::string::npos) << r->body;
      EXPECT_EQ(r->body.find("epr_"), std::string::npos) << r->body;
      EXPECT_EQ(png_size(r->body), std::make_pair(0u, 0u));
      if (path == "/") {
        EXPECT_EQ(r->get_header_value("Content-Type"), "text/html; charset=utf-8");
        EXPECT_NE(r->body.find("id=\"token\""), std::string::npos) << "GET / without a token is the login page";
        EXPECT_EQ(r->body.find("window.eprDashboard"), std::string::npos);
      } else {
        EXPECT_EQ(r->get_header_value("Content-Type"), "application/json");
        const json e = json::parse(r->body, nullptr, false);
        EXPECT_EQ(e["reason"], "unauthorized") << r->body;
      }
    }
  }
  // The probes stay open.
  EXPECT_EQ(get_json(http, "/healthz"), (json{{"status", "ok"}}));
  EXPECT_EQ(get_json(http, "/readyz")["ready"], true);
}

TEST_F(MonitoringAuthTest, TheBearerTokenOpensEveryRoute) {
  auto http = http_client(*master_);
  http.set_bearer_token_auth(kToken.c_str());
  for (const std::string& path : protected_paths()) {
    SCOPED_TRACE(path);
    auto r = http.Get(path.c_str());
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, path == "/login" ? 204 : 200) << r->body;
  }
  const json list = get_json(http, "/api/v1/jobs");
  ASSERT_EQ(list["jobs"].size(), 1u);
  EXPECT_EQ(list["jobs"][0]["id"], id_);
  auto png = http.Get(("/api/v1/jobs/" + id_ + "/image.png").c_str());
  ASSERT_TRUE(png);
  EXPECT_EQ(png_size(png->body), std::make_pair(64u, 48u));
  auto page = http.Get("/");
  ASSERT_TRUE(page);
  EXPECT_NE(page->body.find("window.eprDashboard"), std::string::npos);
  // Writes are still refused, token or not.
  auto post = http.Post("/api/v1/jobs", "{}", "application/json");
  ASSERT_TRUE(post);
  EXPECT_EQ(post->status, 405);
}

TEST_F(MonitoringAuthTest, TheSchemeIsCaseInsensitive) {
  // RFC 7235: "bearer", "BEARER" and "Bearer" are one scheme; one or more spaces part it from the token.
  auto http = http_client(*master_);
  for (const std::string scheme : {"bearer ", "BEARER ", "bEaReR ", "Bearer   "}) {
    for (const char* path : {"/metrics", "/api/v1/jobs"}) {
      SCOPED_TRACE(scheme + path);
      auto r = http.Get(path, {{"Authorization", scheme + kToken}});
      ASSERT_TRUE(r);
      EXPECT_EQ(r->status, 200) << r->body;
    }
  }
}

TEST_F(MonitoringAuthTest, LoginSetsAStrictHttpOnlySessionCookieThatIsNotTheToken) {
  auto http = http_client(*master_);
  auto login = http.Get("/login", {{"Authorization", "Bearer " + kToken}});
  ASSERT_TRUE(login);
  ASSERT_EQ(login->status, 204);
  const std::string set_cookie = login->get_header_value("Set-Cookie");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(set_cookie, m, std::regex("^epr_session=([0-9a-f]{64});"))) << set_cookie;
  const std::string session = m[1];
  for (const char* attribute : {"; HttpOnly", "; SameSite=Strict", "; Path=/"})
    EXPECT_NE(set_cookie.find(attribute), std::string::npos) << attribute << " in " << set_cookie;
  EXPECT_EQ(set_cookie.find("Max-Age"), std::string::npos) << "a session cookie ends with the browser session";
  EXPECT_EQ(set_cookie.find(kToken), std::string::npos) << "the cookie must not carry the token itself";

  // The cookie alone (among others) opens the routes; a changed one does not.
  for (const std::string& path : protected_paths()) {
    SCOPED_TRACE(path);
    auto ok = http.Get(path.c_str(), {{"Cookie", "theme=dark; epr_session=" + session + "; x=1"}});
    ASSERT_TRUE(ok);
    EXPECT_EQ(ok->status, path == "/login" ? 204 : 200);
    std::string forged = session;
    forged[10] = forged[10] == 'a' ? 'b' : 'a';
    auto bad = http.Get(path.c_str(), {{"Cookie", "epr_session=" + forged}});
    ASSERT_TRUE(bad);
    EXPECT_EQ(bad->status, 401);
  }
  // A master with another token does not take this cookie.
  auto other = start_master("cpu", kToken + "2");
  auto other_http = http_client(*other);
  auto r = other_http.Get("/api/v1/jobs", {{"Cookie", "epr_session=" + session}});
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 401);
  other->shutdown();
}

TEST(MonitoringWithoutToken, EverythingStaysOpen) {
  auto master = start_master();
  auto http = http_client(*master);
  for (const char* path : {"/", "/api/v1/jobs", "/api/v1/workers", "/metrics", "/healthz", "/readyz"}) {
    SCOPED_TRACE(path);
    auto r = http.Get(path);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 200);
    EXPECT_FALSE(r->has_header("WWW-Authenticate"));
  }
  master->shutdown();
}

}  // namespace
}  // namespace epr::monitoring_test
