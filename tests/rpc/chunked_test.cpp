// Chunked transfers (wire/rpc/chunked.h): how blobs are cut, how pieces are checked on arrival, and
// the SceneChunk stream of a scene bundle.
#include "wire/rpc/chunked.h"

#include <gtest/gtest.h>

namespace epr::rpc {
namespace {

TEST(Chunked, BlobsAreCutIntoPiecesOfAtMostOneMebibyte) {
  const std::string blob = std::string(kChunkBytes, 'a') + std::string(kChunkBytes, 'b') + "c";
  std::vector<std::pair<uint64_t, std::string>> pieces;
  EXPECT_TRUE(for_each_chunk(blob, [&](uint64_t offset, std::string_view piece) {
    pieces.emplace_back(offset, std::string(piece));
    return true;
  }));
  ASSERT_EQ(pieces.size(), 3u);
  EXPECT_EQ(pieces[0].first, 0u);
  EXPECT_EQ(pieces[1].first, kChunkBytes);
  EXPECT_EQ(pieces[2], std::make_pair(uint64_t(2 * kChunkBytes), std::string("c")));
  EXPECT_EQ(pieces[0].second + pieces[1].second + pieces[2].second, blob);

  int calls = 0;
  EXPECT_TRUE(for_each_chunk("", [&](uint64_t, std::string_view) { return ++calls, true; }));
  EXPECT_EQ(calls, 0);
  EXPECT_FALSE(for_each_chunk(blob, [&](uint64_t, std::string_view) { return ++calls, false; }));
  EXPECT_EQ(calls, 1) << "a false from send stops the cutting";
}

TEST(Chunked, TrackerTakesPiecesInOrderWithoutGapsUpToTheSize) {
  ChunkTracker t(10);
  EXPECT_EQ(t.add(0, 4), std::nullopt);
  EXPECT_EQ(t.add(0, 4), "data at offset 0, expected 4") << "a repeated piece";
  EXPECT_EQ(t.add(5, 1), "data at offset 5, expected 4") << "a gap";
  EXPECT_EQ(t.add(4, 7), "more than the 10 bytes announced");
  EXPECT_FALSE(t.complete());
  EXPECT_EQ(t.received(), 4u) << "refused pieces are not counted";
  EXPECT_EQ(t.add(4, 6), std::nullopt);
  EXPECT_TRUE(t.complete());
  EXPECT_TRUE(ChunkTracker(0).complete());
}

TEST(Chunked, SceneStreamIsTheManifestThenEveryFileInOrder) {
  SceneBundleData b;
  b.entry_path = "room.obj";
  b.files = {{"room.obj", std::string(kChunkBytes + 5, 'o')}, {"empty.mtl", ""}, {"tex/a.png", "png"}};
  const auto chunks = scene_chunks(b);
  ASSERT_EQ(chunks.size(), 4u) << "manifest, two pieces of room.obj, none for the empty file, one for a.png";
  ASSERT_TRUE(chunks[0].has_manifest());
  const auto& m = chunks[0].manifest();
  EXPECT_EQ(m.content_hash(), content_hash(b));
  EXPECT_EQ(m.entry_path(), "room.obj");
  EXPECT_EQ(m.total_bytes(), b.total_bytes());
  ASSERT_EQ(m.files_size(), 3);
  EXPECT_EQ(m.files(1).path(), "empty.mtl");
  EXPECT_EQ(m.files(1).size_bytes(), 0u);
  EXPECT_EQ(chunks[1].data().file_index(), 0u);
  EXPECT_EQ(chunks[2].data().offset(), kChunkBytes);
  EXPECT_EQ(chunks[2].data().data(), "ooooo");
  EXPECT_EQ(chunks[3].data().file_index(), 2u);
  EXPECT_EQ(chunks[3].data().data(), "png");

  int sent = 0;
  EXPECT_FALSE(send_scene(b, [&](const v1::SceneChunk&) { return ++sent < 2; }));
  EXPECT_EQ(sent, 2) << "a false from send stops the stream";
}

}  // namespace
}  // namespace epr::rpc
