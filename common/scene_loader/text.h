// Reading the text formats of a scene (OBJ and MTL): errors that name file and line, lines split as
// exporters write them, blank-separated tokens and strictly checked numbers.
#pragma once

#include <spdlog/logger.h>

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "common/scene.h"
#include "common/scene_error.h"

namespace epr::loader {

/// The logger of scene input ("common").
std::shared_ptr<spdlog::logger> scene_log();

/// Adds a warning about the scene's input to `report` (and logs it at debug level: it is shown to the
/// user by whoever loads the scene for them, once).
void warn(LoadReport& report, std::string message);

/// Raises SceneError "file:line: reason" (line 0: "file: reason", for files without lines, like glTF).
[[noreturn]] void fail(const std::string& file, size_t line, const std::string& reason);
/// Raises SceneError "file: reason" (a problem with the whole file).
[[noreturn]] void fail_file(const std::string& file, const std::string& reason);
/// Scene::validate(), its complaint raised as SceneError naming `file`.
void validate_or_fail(const Scene& scene, const std::string& file);

/// Splits text into lines: "\n", "\r\n" and a lone "\r" each end a line.
class LineReader {
 public:
  explicit LineReader(std::string_view text) : text_(text) {}

  bool next(std::string_view* line) {
    if (pos_ >= text_.size()) return false;
    size_t end = pos_;
    while (end < text_.size() && text_[end] != '\n' && text_[end] != '\r') ++end;
    *line = text_.substr(pos_, end - pos_);
    pos_ = end;
    if (pos_ < text_.size()) {
      if (text_[pos_] == '\r' && pos_ + 1 < text_.size() && text_[pos_ + 1] == '\n') ++pos_;
      ++pos_;
    }
    ++number_;
    return true;
  }
  /// 1-based number of the line next() returned last.
  size_t number() const { return number_; }

 private:
  std::string_view text_;
  size_t pos_ = 0;
  size_t number_ = 0;
};

inline bool is_space(char c) { return c == ' ' || c == '\t'; }

/// Removes a comment (a token starting with '#') and surrounding blanks.
std::string_view strip_comment(std::string_view line);
/// Tokens separated by blanks (spaces and tabs).
void tokenize(std::string_view line, std::vector<std::string_view>* tokens);
/// The statement's argument text: the line after its keyword, without comment and blanks.
std::string_view rest_after_keyword(std::string_view stripped, std::string_view keyword);
/// The token in quotes for a message: at most 40 characters, control characters as '?'.
std::string quote_token(std::string_view token);
/// A decimal number (read as a double, returned as the nearest float) that must be finite and at
/// most `limit` in magnitude; failures raise file:line naming `what`.
float parse_real(std::string_view tok, double limit, const std::string& file, size_t line, const char* what);
/// The statements of an OBJ or MTL text, one per call of next(): lines split by LineReader, a NUL
/// byte refused naming file and line, comments stripped, blank lines skipped.
class StatementReader {
 public:
  StatementReader(std::string_view text, const std::string& file) : lines_(text), file_(file) {}
  /// Moves to the next statement; false at the end of the text.
  bool next() {
    std::string_view raw;
    while (lines_.next(&raw)) {
      if (raw.find('\0') != std::string_view::npos) fail(file_, lines_.number(), "NUL byte in a text file");
      line_ = strip_comment(raw);
      tokenize(line_, &tokens_);
      if (!tokens_.empty()) return true;
    }
    return false;
  }
  size_t line_number() const { return lines_.number(); }
  std::string_view line() const { return line_; }  // without its comment and surrounding blanks
  const std::vector<std::string_view>& tokens() const { return tokens_; }

 private:
  LineReader lines_;
  const std::string& file_;
  std::string_view line_;
  std::vector<std::string_view> tokens_;
};

/// Splits an mtllib argument: blanks separate names, a backslash escapes the next character.
std::vector<std::string> split_escaped(std::string_view s);

}  // namespace epr::loader
