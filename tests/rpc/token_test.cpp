// The bearer-token rule (wire/rpc/token.h): whole file, trailing white space trimmed, one token of
// printable ASCII, $EPR_TOKEN as the fallback, a warning for files open to other users.
#include "wire/rpc/token.h"

#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <sys/stat.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include "common/log.h"

namespace epr::rpc {
namespace {

class TokenFile : public ::testing::Test {
 protected:
  void SetUp() override {
    unsetenv("EPR_TOKEN");
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = ::testing::TempDir() + "/epr-token-" + info->name();
  }
  void TearDown() override {
    std::remove(path_.c_str());
    unsetenv("EPR_TOKEN");
  }
  const std::string& write(const std::string& text, mode_t mode = 0600) {
    std::ofstream(path_, std::ios::binary | std::ios::trunc) << text;
    ::chmod(path_.c_str(), mode);
    return path_;
  }
  // The message of the TokenError `f` throws ("" if it throws none).
  template <class F>
  static std::string error_of(F f) {
    try {
      f();
    } catch (const TokenError& e) {
      return e.what();
    }
    return "";
  }
  std::string path_;
};

TEST_F(TokenFile, WholeFileWithTrailingWhiteSpaceTrimmed) {
  EXPECT_EQ(read_token_file(write("s3cret\n")), "s3cret");
  EXPECT_EQ(read_token_file(write("s3cret\r\n\n  \t")), "s3cret");
  EXPECT_EQ(read_token_file(write("s3cret")), "s3cret");
  EXPECT_EQ(read_token_file(write("a-b_c.d~e+f/g=")), "a-b_c.d~e+f/g=");
}

TEST_F(TokenFile, EmptyOrMissingIsRefusedNamingTheFile) {
  const std::string empty = error_of([&] { read_token_file(write("")); });
  EXPECT_NE(empty.find("is empty"), std::string::npos) << empty;
  EXPECT_NE(empty.find(path_), std::string::npos) << empty;
  EXPECT_NE(error_of([&] { read_token_file(write(" \n\n")); }).find("is empty"), std::string::npos);
  const std::string missing = error_of([&] { read_token_file(path_ + ".missing"); });
  EXPECT_NE(missing.find("cannot read"), std::string::npos) << missing;
}

TEST_F(TokenFile, OnlyOneTokenOfPrintableAsciiIsAccepted) {
  // Only trailing white space is ignored: a second line, an inner or a leading space is refused
  // rather than silently cut off (the master and its workers must read the same token).
  for (const std::string text :
       {"zqfirst\nzqsecond\n", "zqtwo words\n", " zqleading\n", "zqtab\there", "zqcaf\xc3\xa9\n"}) {
    const std::string err = error_of([&] { read_token_file(write(text)); });
    EXPECT_NE(err.find("printable ASCII"), std::string::npos) << "'" << text << "': " << err;
    EXPECT_EQ(err.find("zq"), std::string::npos) << "the error must not echo the token: " << err;
  }
}

TEST(Token, ValidTokensArePrintableAsciiWithoutSpaces) {
  EXPECT_TRUE(is_valid_token("abc.DEF-123_~+/="));
  EXPECT_FALSE(is_valid_token(""));
  EXPECT_FALSE(is_valid_token("abc\n")) << "a token given in code is not trimmed";
  EXPECT_FALSE(is_valid_token("abc def"));
  EXPECT_FALSE(is_valid_token("abc\x7f"));
}

TEST_F(TokenFile, WarnsWhenOtherUsersCanReadIt) {
  std::ostringstream log;
  auto sink = std::make_shared<spdlog::sinks::ostream_sink_mt>(log);
  auto rpc_log = logger("rpc");
  rpc_log->sinks().push_back(sink);
  read_token_file(write("tok\n", 0600));
  const std::string quiet = log.str();
  read_token_file(write("tok\n", 0644));
  const std::string loud = log.str();
  rpc_log->sinks().pop_back();
  EXPECT_EQ(quiet, "");
  EXPECT_NE(loud.find("chmod 600"), std::string::npos) << loud;
  EXPECT_EQ(loud.find("tok\n"), std::string::npos) << "the token must not be logged";
}

TEST_F(TokenFile, FileFirstThenTheEnvironment) {
  EXPECT_EQ(configured_token(""), std::nullopt);
  setenv("EPR_TOKEN", "", 1);
  EXPECT_EQ(configured_token(""), std::nullopt);
  setenv("EPR_TOKEN", "from-env\n", 1);
  EXPECT_EQ(configured_token(""), "from-env");
  EXPECT_EQ(configured_token(write("from-file\n")), "from-file");
  setenv("EPR_TOKEN", "two words", 1);
  EXPECT_NE(error_of([&] { configured_token(""); }).find("$EPR_TOKEN"), std::string::npos);
  EXPECT_NE(error_of([&] { configured_token(path_ + ".missing"); }).find("cannot read"), std::string::npos);
}

}  // namespace
}  // namespace epr::rpc
