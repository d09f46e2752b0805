// The byte-level encoding of checkpoint payloads (checkpoint.h): a writer that appends to a string
// or streams to a sink in bounded chunks, a reader over a string or a file source, and the encoding
// of a frame. Internal to master/server/checkpoint*.cpp.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "master/frame_state.h"
#include "master/server/checkpoint_error.h"

namespace epr::checkpoint_io {

// Appends to a string, or (with a sink) hands the bytes on in chunks of about kChunk: small values
// are gathered in a bounded buffer, large arrays go to the sink straight from their memory.
class ByteWriter {
 public:
  static constexpr size_t kChunk = size_t(4) << 20;
  ByteWriter() = default;
  explicit ByteWriter(std::function<void(std::string_view)> sink) : sink_(std::move(sink)) {}
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    put_bytes(&v, sizeof(T));
  }
  void put_bytes(const void* data, size_t n) {
    const char* p = static_cast<const char*>(data);
    if (!sink_ || n < kChunk / 4) {
      out_.append(p, n);
      if (sink_ && out_.size() >= kChunk) flush();
      return;
    }
    flush();
    for (size_t off = 0; off < n; off += kChunk) sink_(std::string_view(p + off, std::min(kChunk, n - off)));
  }
  void put_string(std::string_view s) {
    put<uint64_t>(s.size());
    put_bytes(s.data(), s.size());
  }
  template <class T>
  void put_vector(std::span<const T> v) {
    static_assert(std::is_trivially_copyable_v<T>);
    put<uint64_t>(v.size());
    put_bytes(v.data(), v.size_bytes());
  }
  template <class T>
  void put_vector(const std::vector<T>& v) {
    put_vector(std::span<const T>(v));
  }
  /// Hands what is buffered to the sink (a no-op without one).
  void flush() {
    if (sink_ && !out_.empty()) {
      sink_(out_);
      out_.clear();
    }
  }
  std::string take() { return std::move(out_); }

 private:
  std::function<void(std::string_view)> sink_;
  std::string out_;
};

// Reads from a string, or (with a source) from a file a chunk at a time: `source(buf, n)` returns
// the next bytes, at most n (0: the end).
class ByteReader {
 public:
  explicit ByteReader(std::string_view in) : in_(in), left_(0) {}
  ByteReader(std::function<size_t(char*, size_t)> source, uint64_t length)
      : source_(std::move(source)), left_(length) {}
  template <class T>
  T get() {
    static_assert(std::is_trivially_copyable_v<T>);
    T v;
    get_bytes(&v, sizeof(T));
    return v;
  }
  bool get_bool() {
    const auto b = get<uint8_t>();
    if (b > 1) throw CheckpointError("malformed payload: a flag is neither 0 nor 1");
    return b != 0;
  }
  std::string get_string() {
    const uint64_t n = get<uint64_t>();
    if (n > remaining()) throw CheckpointError("malformed payload: it ends early");
    std::string s(n, '\0');
    get_bytes(s.data(), n);
    return s;
  }
  template <class T>
  std::vector<T> get_vector() {
    const uint64_t n = get<uint64_t>();
    if (n > remaining() / sizeof(T)) throw CheckpointError("malformed payload: an array runs past its end");
    std::vector<T> v(n);
    get_bytes(v.data(), n * sizeof(T));
    return v;
  }
  void get_bytes(void* dst, uint64_t n) {
    if (n > remaining()) throw CheckpointError("malformed payload: it ends early");
    char* d = static_cast<char*>(dst);
    while (n > 0) {
      if (pos_ == in_.size()) refill();
      const size_t m = size_t(std::min<uint64_t>(n, in_.size() - pos_));
      std::memcpy(d, in_.data() + pos_, m);
      pos_ += m;
      d += m;
      n -= m;
    }
  }
  /// Passes over n bytes (a file source: seeks, reads nothing).
  void skip(uint64_t n) {
    if (n > remaining()) throw CheckpointError("malformed payload: it ends early");
    const size_t here = size_t(std::min<uint64_t>(n, in_.size() - pos_));
    pos_ += here;
    n -= here;
    if (n > 0) {
      skip_source_(n);
      left_ -= n;
      consumed_ += n;
    }
  }
  /// Bytes read so far.
  uint64_t offset() const { return consumed_ + pos_; }
  uint64_t remaining() const { return (in_.size() - pos_) + left_; }
  void expect_end() const {
    if (remaining() != 0) throw CheckpointError("malformed payload: trailing bytes");
  }
  std::function<void(uint64_t)> skip_source_;  // a file source: how to pass over bytes unread

 private:
  void refill() {
    consumed_ += in_.size();
    buf_.resize(size_t(std::min<uint64_t>(left_, ByteWriter::kChunk)));
    size_t got = 0;
    while (got < buf_.size()) {
      const size_t n = source_(buf_.data() + got, buf_.size() - got);
      if (n == 0) throw CheckpointError("torn: the file ends early");
      got += n;
    }
    left_ -= got;
    in_ = buf_;
    pos_ = 0;
  }
  std::function<size_t(char*, size_t)> source_;
  std::string buf_;
  std::string_view in_;
  size_t pos_ = 0;
  uint64_t left_;  // bytes of the source not in in_ yet
  uint64_t consumed_ = 0;
};

void put(ByteWriter& w, const FrameProgress& p);
FrameProgress get_progress(ByteReader& r);
void put(ByteWriter& w, const ReprojectionCounts& c);
ReprojectionCounts get_counts(ByteReader& r);
/// The frame, its accumulation visited a span at a time (format version 3).
void put(ByteWriter& w, const FrameView& f);
/// The frame up to its accumulation's cells; returns the number of cells that follow (0 without).
uint64_t get_frame_head(ByteReader& r, FrameSnapshot* f, uint32_t version);
/// The whole frame, its accumulation converted from cells.
FrameSnapshot get_frame(ByteReader& r, uint32_t version);

}  // namespace epr::checkpoint_io
