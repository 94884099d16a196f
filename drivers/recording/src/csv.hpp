// Internal: the syntax shared by every cdpr CSV file (metadata lines, header, numeric rows).
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "cdpr/recording/recording.hpp"
#include "cdpr/status.hpp"

namespace cdpr::recording::detail {

struct CsvRow {
  int line = 0;                         // 1-based line number in the file
  std::vector<std::string_view> cells;  // trimmed; views into the parsed text
};

struct CsvTable {
  std::string name;  // file name for messages
  Metadata metadata;
  int units_line = 0;
  int header_line = 0;
  std::vector<std::string> header;  // trimmed column names
  std::vector<CsvRow> rows;

  // Index of a column by name, or -1.
  int column(std::string_view column_name) const;
};

// Splits text into metadata, header and rows; checks the units statement, duplicate or empty
// column names, that every row has as many cells as the header and that there is at least one
// row. `name` stands for the file in messages.
Result<CsvTable> parse_table(std::string_view text, std::string_view name);

// Reads a whole file into memory.
Result<std::string> read_file(const std::string& path);
// Replaces the file atomically (cdpr/io/atomic_file.hpp): a crash leaves the old or the new file.
Status write_file(const std::string& path, const std::string& text);

// Cell parsers: on failure, a Status "<file>:<line>: column <c> (<name>): <reason>".
Status cell_error(const CsvTable& t, const CsvRow& row, int col, const char* reason_fmt, ...)
    __attribute__((format(printf, 4, 5)));
// A finite number; `allow_empty` turns an empty cell into NaN.
Status parse_double(const CsvTable& t, const CsvRow& row, int col, bool allow_empty, double* out);
Status parse_int(const CsvTable& t, const CsvRow& row, int col, std::int64_t* out);

// Writes the metadata block with `format` and `units` first.
Status format_metadata(const Metadata& metadata, std::string_view format, std::string* out);

}  // namespace cdpr::recording::detail
