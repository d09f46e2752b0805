// The dashboard in a real browser: Debian's Chromium, headless, driven by chromedriver over the
// WebDriver protocol (plain HTTP, cpp-httplib). The test drives the render's rounds itself
// (ManualWorker), so "progress advances" and "the preview changes between rounds" are checked at
// known moments rather than raced against a free-running render. The master requires a bearer token,
// so the test first signs in through the page's login form (a wrong token is refused, the right one
// sets the HttpOnly session cookie the page's requests then carry). It reads what the page shows from
// window.eprDashboard (kept by the page from the same JSON it renders) and from the DOM, and saves
// screenshots to <build>/Testing/monitoring/ (dashboard_running.png, dashboard_samples.png,
// dashboard_done.png).
#include <gtest/gtest.h>

#include "client/job_client.h"
#include "monitoring_helpers.h"

namespace epr::monitoring_test {
namespace {

const char* const kChromium = "/usr/bin/chromium";
const char* const kChromedriver = "/usr/bin/chromedriver";

std::string base64_decode(const std::string& in) {
  std::string out;
  uint32_t acc = 0;
  int bits = 0;
  for (char c : in) {
    int v;
    if (c >= 'A' && c <= 'Z')
      v = c - 'A';
    else if (c >= 'a' && c <= 'z')
      v = c - 'a' + 26;
    else if (c >= '0' && c <= '9')
      v = c - '0' + 52;
    else if (c == '+')
      v = 62;
    else if (c == '/')
      v = 63;
    else
      continue;  // padding, line breaks
    acc = (acc << 6) | uint32_t(v);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out.push_back(char((acc >> bits) & 0xff));
    }
  }
  return out;
}

/// A WebDriver session on a headless Chromium.
class Browser {
 public:
  explicit Browser(const fs::path& dir) : profile_(dir / "profile") {
    fs::create_directories(profile_);
    driver_ =
        std::make_unique<ChildProcess>(std::vector<std::string>{kChromedriver, "--port=0"}, dir / "chromedriver.log");
    const std::string port = driver_->wait_for_output(std::regex("started successfully on port ([0-9]+)"), 30);
    if (port.empty()) throw std::runtime_error("chromedriver did not start: " + driver_->output());
    http_ = std::make_unique<httplib::Client>("127.0.0.1", std::stoi(port));
    http_->set_read_timeout(120, 0);
    const json args = {"--headless",
                       "--no-sandbox",
                       "--disable-gpu",
                       "--disable-quic",
                       "--no-first-run",
                       "--disable-background-networking",
                       "--disable-component-update",
                       "--disable-sync",
                       "--user-data-dir=" + profile_.string(),
                       "--window-size=1400,1250",
                       "--hide-scrollbars"};
    const json caps = {
        {"capabilities",
         {{"alwaysMatch",
           {{"browserName", "chrome"}, {"goog:chromeOptions", {{"binary", kChromium}, {"args", args}}}}}}}};
    session_ = call("POST", "/session", caps)["sessionId"].get<std::string>();
  }
  ~Browser() {
    if (!session_.empty()) http_->Delete(("/session/" + session_).c_str());
    driver_.reset();
    std::error_code ec;
    fs::remove_all(profile_, ec);
  }

  void open(const std::string& url) { call("POST", path("/url"), {{"url", url}}); }
  json eval(const std::string& script) {
    return call("POST", path("/execute/sync"), {{"script", script}, {"args", json::array()}});
  }
  json state() { return eval("return window.eprDashboard || null;"); }
  void screenshot(const fs::path& file) {
    const std::string png = base64_decode(call("GET", path("/screenshot"), nullptr).get<std::string>());
    fs::create_directories(file.parent_path());
    std::ofstream(file, std::ios::binary) << png;
  }
  /// Waits until the page is still: the preview image (if shown) decoded and no CSS transition (the
  /// progress bar's) running. For screenshots that show what the page settled on.
  bool wait_still(double seconds) {
    return wait_for(
        [&] {
          return eval(
                     "const i = document.getElementById('preview');"
                     "return (i.hidden || (i.complete && i.naturalWidth > 0)) && document.getAnimations().length === "
                     "0;")
              .get<bool>();
        },
        seconds);
  }
  /// Waits until `predicate(state())` holds; the last state for messages.
  template <typename F>
  bool wait_state(F predicate, double seconds, json* last) {
    return wait_for(
        [&] {
          *last = state();
          return !last->is_null() && predicate(*last);
        },
        seconds);
  }

 private:
  std::string path(const std::string& tail) const { return "/session/" + session_ + tail; }
  json call(const std::string& method, const std::string& p, const json& body) {
    httplib::Result r =
        method == "GET" ? http_->Get(p.c_str()) : http_->Post(p.c_str(), body.dump(), "application/json");
    if (!r) throw std::runtime_error("WebDriver " + p + ": " + httplib::to_string(r.error()));
    json out = json::parse(r->body);
    if (r->status != 200) throw std::runtime_error("WebDriver " + p + ": " + r->body);
    if (out.contains("sessionId") && !out["sessionId"].is_null() && out["sessionId"] != "") return out;  // legacy shape
    return out["value"];
  }

  fs::path profile_;
  std::unique_ptr<ChildProcess> driver_;
  std::unique_ptr<httplib::Client> http_;
  std::string session_;
};

fs::path artefact_dir() { return fs::path(EPR_ARTEFACT_DIR); }

TEST(DashboardBrowser, ProgressAndPreviewAdvanceRoundByRound) {
  ASSERT_TRUE(fs::exists(kChromium) && fs::exists(kChromedriver))
      << "Chromium or chromedriver not installed: run scripts/setup.sh";
  const fs::path dir = scratch_dir("browser");
  const std::string token = "browser-test-token";
  auto master = start_master("cpu", token);
  JobClientOptions co;
  co.token = token;
  JobClient client(master->local_target(), co);
  RenderOptions o = small_job(24);
  o.width = 160;
  o.height = 120;
  o.tile_size = 40;
  o.spp = 24;
  const std::string id = client.submit(o);
  auto round_of = [&] { return master->jobs().get(id)->progress.round; };

  std::unique_ptr<Browser> browser;
  try {
    browser = std::make_unique<Browser>(dir);
  } catch (const std::exception& e) {
    FAIL() << e.what();
  }
  browser->open(master->dashboard_url());
  // Signed out: the login page, no dashboard. A wrong token is refused on the page.
  EXPECT_TRUE(browser->state().is_null());
  auto sign_in = [&](const std::string& t) {
    browser->eval("document.getElementById('token').value = " + json(t).dump() +
                  "; document.getElementById('login').requestSubmit(); return null;");
  };
  sign_in(token + "-wrong");
  ASSERT_TRUE(wait_for(
      [&] { return browser->eval("const e = document.getElementById('error'); return e ? e.textContent : '';") != ""; },
      30));
  EXPECT_NE(browser->eval("return document.getElementById('error').textContent;").get<std::string>().find("not valid"),
            std::string::npos);
  EXPECT_TRUE(browser->state().is_null());
  sign_in(token);
  json s;
  ASSERT_TRUE(browser->wait_state([&](const json& st) { return st["polls"].get<int>() >= 1; }, 30, &s))
      << "the dashboard did not open after signing in";
  // The session cookie is HttpOnly: the page's scripts cannot read it.
  EXPECT_EQ(browser->eval("return document.cookie;"), "");
  // Before the first round: the job is listed and selected, and the preview is a placeholder.
  ManualWorker worker(master->local_target(), token);
  ASSERT_TRUE(
      browser->wait_state([&](const json& st) { return st["jobId"] == id && st["polls"].get<int>() >= 1; }, 30, &s))
      << s;
  EXPECT_EQ(s["previewLoads"], 0);
  EXPECT_EQ(browser->eval("return document.getElementById('preview-ph').hidden;"), false);

  // Round 0 closes: the page shows round 1 and loads a preview.
  worker.work_available();
  ASSERT_TRUE(wait_for([&] { return round_of() >= 1; }, 30));
  ASSERT_TRUE(browser->wait_state(
      [&](const json& st) { return st["round"].get<int>() >= 1 && st["previewLoads"].get<int>() >= 1; }, 30, &s))
      << s;
  const std::string digest1 = s["previewDigest"];
  const double spp1 = s["meanSpp"];
  EXPECT_FALSE(digest1.empty());
  EXPECT_EQ(browser->eval("return document.getElementById('preview').naturalWidth;"), o.width);

  // The master refreshes previews at most once a second, a rule of wall time: close the next round
  // only after that second (counted from round 1's preview, which the page has shown) has passed.
  std::this_thread::sleep_for(std::chrono::milliseconds(1100));
  worker.work_available();
  ASSERT_TRUE(wait_for([&] { return round_of() >= 2; }, 30));
  ASSERT_TRUE(browser->wait_state(
      [&](const json& st) { return st["round"].get<int>() >= 2 && st["previewDigest"] != digest1; }, 30, &s))
      << "the preview did not change between rounds: " << s;
  EXPECT_GT(s["meanSpp"].get<double>(), spp1);
  EXPECT_EQ(s["errors"], 0);

  // A few more rounds, each seen by the page before the next, so that the chart has a point per
  // round; then the running screenshot.
  for (int i = 0; i < 4; ++i) {
    worker.work_available();
    ASSERT_TRUE(browser->wait_state([&](const json& st) { return st["round"].get<int>() >= round_of(); }, 30, &s)) << s;
  }
  const std::string bar = browser->eval("return document.querySelector('#j-bar > div').style.width;");
  EXPECT_NE(bar, "0%");
  EXPECT_TRUE(browser->wait_still(30));
  browser->screenshot(artefact_dir() / "dashboard_running.png");

  // Switching the layer loads the M' heat map.
  const std::string before_switch = s["previewDigest"];
  browser->eval("document.querySelector('#layers [data-layer=samples]').click(); return null;");
  ASSERT_TRUE(browser->wait_state(
      [&](const json& st) { return st["previewDigest"] != before_switch && st["previewLayer"] == "samples"; }, 30, &s))
      << s;
  EXPECT_NE(browser->eval("return document.getElementById('preview-size').textContent;").get<std::string>().find("M′"),
            std::string::npos);
  EXPECT_TRUE(browser->wait_still(30));
  browser->screenshot(artefact_dir() / "dashboard_samples.png");
  browser->eval("document.querySelector('#layers [data-layer=combined]').click(); return null;");

  // Finish the job: the page ends at done, 100 %.
  ASSERT_TRUE(wait_for(
      [&] {
        worker.work_available();
        const auto snap = master->jobs().get(id);
        return snap->state == JobState::kDone;
      },
      120));
  ASSERT_TRUE(browser->wait_state([&](const json& st) { return st["state"] == "done"; }, 30, &s)) << s;
  EXPECT_EQ(browser->eval("return parseFloat(document.querySelector('#j-bar > div').style.width);"), 100);
  EXPECT_EQ(s["errors"], 0);
  EXPECT_TRUE(browser->wait_still(30));
  browser->screenshot(artefact_dir() / "dashboard_done.png");
  EXPECT_GT(fs::file_size(artefact_dir() / "dashboard_done.png"), 10000u);
  browser.reset();
  master->shutdown();
}

}  // namespace
}  // namespace epr::monitoring_test
