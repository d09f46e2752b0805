// A raw SubmitJob (no `epr` client loaded the scene first) of a scene without light: the master
// refuses it with INVALID_ARGUMENT and the reason, naming the scene's file as the submitter named
// it, not by its place in the master's cache (issue 16).
#include <gtest/gtest.h>

#include <string>

#include "client/job_client.h"
#include "master/server/master_server.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"

namespace epr {
namespace {

const std::string kTriangle = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";

v1::JobSpec raw_spec(const std::string& mtl) {
  SceneBundleData b;
  b.entry_path = "dark.obj";
  b.files = {{"dark.mtl", mtl}, {"dark.obj", "mtllib dark.mtl\n" + kTriangle + "usemtl m\nf 1 2 3\n"}};
  RenderOptions ro;
  ro.scene = "dark.obj";
  ro.width = ro.height = 16;
  ro.spp = 1;
  v1::JobSpec spec = to_job_spec(ro, b, CameraSpec{});
  spec.set_name("raw");
  return spec;
}

TEST(UnlitSubmit, RawSubmissionOfAnUnlitSceneIsInvalidArgumentWithTheReason) {
  MasterServerOptions mo;
  mo.listen = "127.0.0.1:0";
  mo.http_listen = "";
  MasterServer master(mo);
  JobClient client(master.local_target());
  for (const std::string mtl : {"newmtl m\nKd 0.5 0.5 0.5\n", "newmtl m\nKd 0.5 0.5 0.5\nKe 0 0 0\n"}) {
    SCOPED_TRACE(mtl);
    try {
      client.submit(raw_spec(mtl));
      ADD_FAILURE() << "the master accepted a scene without light";
    } catch (const RpcError& e) {
      EXPECT_EQ(e.code(), grpc::StatusCode::INVALID_ARGUMENT) << e.what();
      const std::string msg = e.status().error_message();
      EXPECT_EQ(msg.rfind("dark.obj has no light: no material has an emission (Ke)", 0), 0u) << msg;
      EXPECT_NE(msg.find("Ke 10 10 10"), std::string::npos) << msg;
      EXPECT_NE(msg.find("--env 1,1,1"), std::string::npos) << msg;
      EXPECT_NE(msg.find("--sun"), std::string::npos) << msg;
    }
  }
  EXPECT_FALSE(client.submit(raw_spec("newmtl m\nKd 0.5 0.5 0.5\nKe 3 3 3\n")).empty()) << "a lit scene is accepted";
  // The job's sky or sun lights an unlit scene.
  v1::JobSpec sky = raw_spec("newmtl m\nKd 0.5 0.5 0.5\n");
  sky.mutable_environment()->mutable_color()->set_x(1);
  EXPECT_FALSE(client.submit(sky).empty()) << "a scene lit by the job's sky is accepted";
  v1::JobSpec sun = raw_spec("newmtl m\nKd 0.5 0.5 0.5\n");
  sun.mutable_sun()->mutable_direction()->set_y(1);
  EXPECT_FALSE(client.submit(sun).empty()) << "a scene lit by the job's sun is accepted";
  // A job's environment image must be one of the bundle's files, read inside the scene's folder.
  v1::JobSpec image = raw_spec("newmtl m\nKd 0.5 0.5 0.5\n");
  image.mutable_environment()->set_image("../sky.hdr");
  try {
    client.submit(image);
    ADD_FAILURE() << "the master accepted an image path outside the bundle";
  } catch (const RpcError& e) {
    EXPECT_EQ(e.code(), grpc::StatusCode::INVALID_ARGUMENT) << e.what();
    EXPECT_NE(e.status().error_message().find("environment image '../sky.hdr'"), std::string::npos)
        << e.status().error_message();
  }
  master.shutdown();
}

}  // namespace
}  // namespace epr
