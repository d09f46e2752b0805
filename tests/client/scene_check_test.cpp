// A cluster submission loads its scene once where it is rendered: the client only checks it (the
// glTF or OBJ parsed, texture files checked by their headers, no texel decoded) before it uploads it,
// and a standalone master's admission check is the load its job starts from. A texture whose header
// is broken is named at submit; one whose texels are broken by the master's admission, naming the file
// that refers to it as the client knows it, the first in the scene's order.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "client/job_client.h"
#include "common/image.h"
#include "common/scene_loader.h"
#include "master/server/master_server.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {

namespace fs = std::filesystem;

class SceneCheck : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("epr-scene-check-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "scene");
    ::setenv("EPR_CACHE_DIR", (dir_ / "cache").c_str(), 1);  // the master's scene cache
    MasterServerOptions mo;
    mo.listen = "127.0.0.1:0";
    mo.http_listen = "";
    master_ = std::make_unique<MasterServer>(mo);
    JobClientOptions co;
    co.inline_scene_limit = 0;  // uploaded, as a cluster submission of a textured scene is
    client_ = std::make_unique<JobClient>(master_->local_target(), co);
  }
  void TearDown() override {
    client_.reset();
    master_->shutdown();
    ::unsetenv("EPR_CACHE_DIR");
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  static RenderOptions options(const std::string& scene) {
    RenderOptions o;
    o.scene = scene;
    o.width = 32;
    o.height = 24;
    o.spp = 2;
    o.tile_size = 16;
    return o;
  }

  // An OBJ whose materials a and b take their colour from a.png and b.png (box.mtl lines 3 and 6),
  // lit by a third.
  std::string write_obj() const {
    std::ofstream(dir_ / "scene" / "box.mtl") << "newmtl a\nKd 1 1 1\nmap_Kd a.png\n"
                                              << "newmtl b\nKd 1 1 1\nmap_Kd b.png\n"
                                              << "newmtl lamp\nKe 5 5 5\n";
    std::ofstream(dir_ / "scene" / "box.obj") << "mtllib box.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                                              << "usemtl a\nf 1/1 2/2 3/3\nusemtl b\nf 1/1 3/3 2/2\n"
                                              << "usemtl lamp\nf 1 2 3\n";
    return (dir_ / "scene" / "box.obj").string();
  }

  // A size x size PNG of noise; with `keep` > 0, only its first `keep` bytes (the header intact,
  // the texels cut off).
  void write_png(const std::string& name, int size, size_t keep = 0) const {
    Image img(size, size, 3);
    uint32_t s = 12345;
    for (float& v : img.data) v = float((s = s * 1664525u + 1013904223u) >> 8) / float(1u << 24);
    const fs::path path = dir_ / "scene" / name;
    write_png_srgb(path.string(), img);
    if (keep > 0) fs::resize_file(path, keep);
  }

  fs::path dir_;
  std::unique_ptr<MasterServer> master_;
  std::unique_ptr<JobClient> client_;
};

TEST_F(SceneCheck, ASubmissionIsCheckedByTheClientAndLoadedOnceByTheMaster) {
  const RenderOptions o = options(std::string(EPR_SOURCE_DIR) + "/scenes/cutout-lattice/cutout-lattice.gltf");
  const uint64_t loads = scene_file_loads(), checks = scene_file_checks();
  const std::string id = client_->submit(client_->make_job_spec(o));
  EXPECT_EQ(scene_file_checks() - checks, 1u) << "the client checks the scene once";
  EXPECT_EQ(scene_file_loads() - loads, 1u) << "the client decoded textures it only uploads";
  // The job starts (no worker traces it): its scene is the one the admission loaded.
  v1::JobStatus st;
  for (int i = 0; i < 6000; ++i) {
    st = client_->get(id);
    if (st.state() != v1::JOB_STATE_QUEUED) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_EQ(st.state(), v1::JOB_STATE_RUNNING) << st.error_message();
  EXPECT_EQ(scene_file_loads() - loads, 1u) << "the master loaded the scene again for the job's start";
  client_->cancel(id);
}

TEST_F(SceneCheck, TheClientsCheckGivesTheCameraAndFilesOfAFullLoad) {
  const std::string scene = std::string(EPR_SOURCE_DIR) + "/scenes/cutout-lattice/cutout-lattice.gltf";
  const SceneBundleData full = bundle_scene(scene);
  const SceneBundleData checked = bundle_scene(scene, {}, "", BundleLoad::kUpload);
  EXPECT_EQ(checked.loaded, nullptr) << "a checked scene's textures have no texels: it is not to be rendered";
  ASSERT_NE(full.loaded, nullptr);
  EXPECT_EQ(content_hash(checked), content_hash(full));
  ASSERT_TRUE(checked.camera && full.camera);
  EXPECT_EQ(checked.camera->eye, full.camera->eye);
  EXPECT_EQ(checked.camera->look, full.camera->look);
  EXPECT_EQ(checked.camera->fov_y_degrees, full.camera->fov_y_degrees);
}

TEST_F(SceneCheck, ATextureWithABrokenHeaderIsNamedAtSubmit) {
  const std::string obj = write_obj();
  write_png("a.png", 16);
  std::ofstream(dir_ / "scene" / "b.png") << "not an image at all";
  const uint64_t loads = scene_file_loads();
  try {
    client_->make_job_spec(options(obj));
    ADD_FAILURE() << "a texture that is no image was accepted";
  } catch (const SceneError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("box.mtl:6: cannot read texture 'b.png'"), std::string::npos) << msg;
  }
  EXPECT_EQ(scene_file_loads(), loads);
}

TEST_F(SceneCheck, BrokenTexelsAreNamedByTheMastersAdmissionTheFirstInTheScenesOrder) {
  const std::string obj = write_obj();
  write_png("a.png", 32, 120);  // both cut off after their header; b.png, the larger, is decoded first
  write_png("b.png", 96, 120);
  const RenderOptions o = options(obj);
  const uint64_t checks = scene_file_checks();
  const v1::JobSpec spec = client_->make_job_spec(o);  // the client reads headers only: it passes
  EXPECT_EQ(scene_file_checks() - checks, 1u);
  try {
    client_->submit(spec);
    ADD_FAILURE() << "the master accepted a texture whose texels cannot be read";
  } catch (const RpcError& e) {
    EXPECT_EQ(e.code(), grpc::StatusCode::INVALID_ARGUMENT) << e.what();
    const std::string msg = e.status().error_message();
    EXPECT_EQ(msg.rfind("box.mtl:3: cannot read texture 'a.png'", 0), 0u) << msg;
    EXPECT_EQ(msg.find((dir_ / "cache").string()), std::string::npos) << "names the master's cache: " << msg;
  }
  // The same error from a full load on this side, whichever texture a thread decodes first.
  for (int i = 0; i < 3; ++i) {
    try {
      load_scene(obj);
      ADD_FAILURE() << "loaded a scene with broken textures";
    } catch (const SceneError& e) {
      EXPECT_NE(std::string(e.what()).find("box.mtl:3: cannot read texture 'a.png'"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace epr
