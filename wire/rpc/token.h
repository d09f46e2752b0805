// The bearer token that guards the master's services, read the same way by epr-master (the token it
// requires), epr-worker and epr (the token they send). A token lives in a file or in $EPR_TOKEN, never
// on a command line, which `ps` shows, and is never logged.
//
// The rule: the whole file, with trailing white space (the final newline) removed; what remains must
// be non-empty printable ASCII without spaces (it travels as "authorization: Bearer <token>"
// metadata). A file other users can read or write is used with a warning (chmod 600 it).
#pragma once

#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>

namespace epr::rpc {

/// A token file or $EPR_TOKEN that cannot be used; the message names the file and the reason.
class TokenError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The token held in `path`. Throws TokenError if the file cannot be read, is empty, or holds
/// anything but one token of printable ASCII.
std::string read_token_file(const std::string& path);

/// True for one token: non-empty printable ASCII without spaces (what a token file holds once its
/// trailing white space is removed).
bool is_valid_token(std::string_view token);

/// `token_file` if not empty, else $EPR_TOKEN if set and not empty (same rule), else none.
/// Throws TokenError like read_token_file.
std::optional<std::string> configured_token(const std::string& token_file);

}  // namespace epr::rpc
