# Writes OUTPUT, a C++ file defining `std::string_view epr::SYMBOL()` that returns the text of INPUT
# (a raw string literal). Run at build time: cmake -DINPUT=... -DOUTPUT=... -DSYMBOL=... -P embed_text.cmake
file(READ "${INPUT}" content)
string(FIND "${content}" ")EPRTEXT\"" clash)
if(NOT clash EQUAL -1)
  message(FATAL_ERROR "${INPUT} contains the raw-string delimiter )EPRTEXT\"")
endif()
file(WRITE "${OUTPUT}.tmp" "// Generated from ${INPUT} by embed_text.cmake; do not edit.
#include <string_view>

namespace epr {

std::string_view ${SYMBOL}() {
  static constexpr char text[] = R\"EPRTEXT(${content})EPRTEXT\";
  return {text, sizeof(text) - 1};
}

}  // namespace epr
")
file(COPY_FILE "${OUTPUT}.tmp" "${OUTPUT}" ONLY_IF_DIFFERENT)
file(REMOVE "${OUTPUT}.tmp")
