// Writing files so that a crash never leaves half of one.
//
// Every file cdpr writes (recordings, calibrated configs, reports, geometry versions) goes through
// this header. A file is first written in full to a temporary file in the same directory
// (".<name>.tmp-<pid>-<n>"), flushed to the disk (fsync), then renamed over the target and the
// directory is flushed, so that a process killed or a machine losing power at any moment leaves
// either the old file or the new one, never a mix or a truncated file. A temporary left behind
// by a kill is harmless; the next write uses another name.
//
//   CDPR_RETURN_IF_ERROR(io::write_file_atomically("calibrated.yaml", yaml));
//
// Several outputs of one command are written together or not at all:
//
//   io::AtomicFileSet outputs;
//   CDPR_RETURN_IF_ERROR(outputs.stage("report.json", json));   // written and flushed now
//   CDPR_RETURN_IF_ERROR(outputs.stage("report.html", html));
//   CDPR_RETURN_IF_ERROR(outputs.commit());                      // every rename, then the fsyncs
//
// When a stage() fails (no such directory, disk full) nothing is renamed and the temporaries are
// removed (also when the set is destroyed without commit()): every target keeps its old
// content. The renames of commit() happen only after every file is safely on the disk, one after
// the other in microseconds; a crash inside that window can leave some targets new and some old,
// each of them whole. New files get the permissions 0666 minus the umask, like std::ofstream.
//
// Errors are kIoError (kNotFound for a missing directory) naming the path and the reason. Not for
// the RT path: it allocates and makes system calls that may block.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "cdpr/status.hpp"

namespace cdpr::io {

// Replaces (or creates) `path` with `contents`, atomically.
Status write_file_atomically(const std::string& path, std::string_view contents);

// Whether `file_name` (a name, not a path) is one of the temporary files this header writes,
// ".<name>.tmp-<pid>-<n>", and if so the pid of the process that wrote it. A crash between a
// write and its rename leaves one behind; its owner may remove it once no process writes it.
bool is_temporary_name(std::string_view file_name, int* writer_pid = nullptr);

// Tests only (fault injection, e.g. a power loss between write and rename): called with each
// target path after its temporary file is written and flushed, just before it is renamed over the
// target. nullptr (the default): none.
using BeforeRenameHook = void (*)(const std::string& target);
void set_before_rename_hook(BeforeRenameHook hook);

// Outputs of one command, written together.
class AtomicFileSet {
 public:
  AtomicFileSet() = default;
  ~AtomicFileSet();
  AtomicFileSet(const AtomicFileSet&) = delete;
  AtomicFileSet& operator=(const AtomicFileSet&) = delete;

  // Writes `contents` to a temporary beside `path` and flushes it. The target is not touched.
  Status stage(const std::string& path, std::string_view contents);
  // Renames every staged file over its target, then flushes their directories. After an error
  // the files not yet renamed are abandoned. The set is empty afterwards.
  Status commit();
  // Removes the temporaries of the staged files; no target changes.
  void abandon();

  std::size_t staged() const { return files_.size(); }

 private:
  struct Staged {
    std::string target;
    std::string temp;
  };
  std::vector<Staged> files_;
};

}  // namespace cdpr::io
