#include "model/core/text_file.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <system_error>

#include "model/core/errors.h"

namespace flexid::model {
namespace {

constexpr std::size_t kReadChunkBytes = 1 << 16;

bool IsUtf8Continuation(unsigned char byte) { return (byte & 0xC0U) == 0x80U; }

// Length of the well-formed UTF-8 sequence starting at text[i], or 0 if it is not one.
std::size_t Utf8SequenceLength(std::string_view text, std::size_t i) {
  const auto lead = static_cast<unsigned char>(text[i]);
  std::size_t length = 0;
  if (lead >= 0xC2U && lead <= 0xDFU) {
    length = 2;
  } else if (lead >= 0xE0U && lead <= 0xEFU) {
    length = 3;
  } else if (lead >= 0xF0U && lead <= 0xF4U) {
    length = 4;
  } else {
    return 0;
  }
  if (i + length > text.size()) return 0;
  for (std::size_t k = 1; k < length; ++k) {
    if (!IsUtf8Continuation(static_cast<unsigned char>(text[i + k]))) return 0;
  }
  return length;
}

struct FileCloser {
  void operator()(std::FILE* file) const { std::fclose(file); }
};
using FilePointer = std::unique_ptr<std::FILE, FileCloser>;

}  // namespace

std::string ErrnoMessage(int error_number) {
  return std::error_code(error_number, std::generic_category()).message();
}

std::size_t CharacterColumn(std::string_view line, std::size_t byte_offset) {
  byte_offset = std::min(byte_offset, line.size());
  std::size_t column = 1;
  for (std::size_t i = 0; i < byte_offset; ++i) {
    if (!IsUtf8Continuation(static_cast<unsigned char>(line[i]))) ++column;
  }
  return column;
}

std::string Printable(std::string_view text, std::size_t max_characters, bool quote) {
  std::string out;
  std::size_t characters = 0;
  std::size_t i = 0;
  while (i < text.size() && characters < max_characters) {
    const auto byte = static_cast<unsigned char>(text[i]);
    if (quote && (byte == '"' || byte == '\\')) {
      out += '\\';
      out += static_cast<char>(byte);
      ++i;
    } else if (byte >= 0x20U && byte < 0x7FU) {
      out += static_cast<char>(byte);
      ++i;
    } else if (const std::size_t length = Utf8SequenceLength(text, i); length > 0) {
      out.append(text.substr(i, length));
      i += length;
    } else {
      std::array<char, 5> escaped{};
      std::snprintf(escaped.data(), escaped.size(), "\\x%02X", static_cast<unsigned>(byte));
      out += escaped.data();
      ++i;
    }
    ++characters;
  }
  if (quote) out = "\"" + out + "\"";
  if (i < text.size()) out += "...";
  return out;
}

std::string Quoted(std::string_view text, std::size_t max_characters) {
  return Printable(text, max_characters, true);
}

std::string ReadWholeFile(const std::string& path, std::size_t max_bytes,
                          std::string_view too_large_problem) {
  errno = 0;
  FilePointer file(std::fopen(path.c_str(), "rb"));
  if (!file) throw InputError(path + ": cannot open: " + ErrnoMessage(errno));
  struct stat status {};
  const bool have_status = ::fstat(::fileno(file.get()), &status) == 0;
  if (have_status && S_ISDIR(status.st_mode)) {
    throw InputError(path + ": cannot open: " + ErrnoMessage(EISDIR));
  }
  auto too_large = [&]() { return InputError(path + ": " + std::string(too_large_problem)); };
  std::string contents;
  if (have_status && S_ISREG(status.st_mode) && status.st_size > 0) {
    const auto size = static_cast<std::uintmax_t>(status.st_size);
    if (size > max_bytes) throw too_large();
    contents.reserve(static_cast<std::size_t>(size));
  }
  std::array<char, kReadChunkBytes> buffer{};
  while (true) {
    const std::size_t read = std::fread(buffer.data(), 1, buffer.size(), file.get());
    contents.append(buffer.data(), read);
    if (contents.size() > max_bytes) throw too_large();
    if (read < buffer.size()) break;
  }
  if (std::ferror(file.get())) throw InputError(path + ": cannot read: " + ErrnoMessage(errno));
  return contents;
}

void WriteFileAtomically(const std::string& path, std::string_view contents) {
  const std::string temporary_path = path + ".tmp";
  auto fail = [&](const std::string& what, int error_number) {
    std::remove(temporary_path.c_str());
    throw InputError(path + ": " + what + ": " + ErrnoMessage(error_number));
  };
  errno = 0;
  FilePointer file(std::fopen(temporary_path.c_str(), "wb"));
  if (!file) throw InputError(path + ": cannot write: " + ErrnoMessage(errno));
  if (std::fwrite(contents.data(), 1, contents.size(), file.get()) != contents.size() ||
      std::fflush(file.get()) != 0 || ::fsync(::fileno(file.get())) != 0) {
    const int error_number = errno;
    file.reset();
    fail("cannot write", error_number);
  }
  if (std::fclose(file.release()) != 0) fail("cannot write", errno);
  if (std::rename(temporary_path.c_str(), path.c_str()) != 0) fail("cannot rename", errno);
}

}  // namespace flexid::model
