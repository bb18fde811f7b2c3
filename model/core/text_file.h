// Internal helpers shared by the readers and writers of flexid's text files (model files,
// recordings, predictions): one-line messages that quote outside text safely, whole-file
// reads with a size limit and atomic writes. Failures are model::InputError whose message
// starts with the path. Not part of the library's public interface.
#pragma once

#include <cstddef>
#include <limits>
#include <string>
#include <string_view>

namespace flexid::model {

// Characters of outside text that Quoted keeps before cutting it with "...".
inline constexpr std::size_t kMaxQuotedCharacters = 40;

// The text of an errno value, e.g. "No such file or directory".
std::string ErrnoMessage(int error_number);

// 1-based column, in characters (UTF-8 code points), of byte_offset within line.
std::size_t CharacterColumn(std::string_view line, std::size_t byte_offset);

// Text made safe for a one-line message: at most max_characters characters ("..."
// appended when cut), control characters and malformed UTF-8 as \xNN; well-formed UTF-8
// is kept. When `quote` is set the result is in double quotes, with quotes and
// backslashes inside escaped.
std::string Printable(std::string_view text, std::size_t max_characters, bool quote);

// Printable(text, max_characters, true): the text in double quotes, e.g. "t_s".
std::string Quoted(std::string_view text, std::size_t max_characters = kMaxQuotedCharacters);

// The bytes of the file at path. Throws InputError "PATH: cannot open: REASON" (also for a
// directory), "PATH: cannot read: REASON", or "PATH: " + too_large_problem when the file
// holds more than max_bytes bytes.
std::string ReadWholeFile(const std::string& path,
                          std::size_t max_bytes = std::numeric_limits<std::size_t>::max(),
                          std::string_view too_large_problem = "file is too large");

// Writes PATH.tmp, flushes it to disk and renames it over PATH, so that readers see either
// the old file or the complete new one. Throws InputError "PATH: cannot write: REASON" or
// "PATH: cannot rename: REASON"; PATH.tmp is removed when it was created.
void WriteFileAtomically(const std::string& path, std::string_view contents);

}  // namespace flexid::model
