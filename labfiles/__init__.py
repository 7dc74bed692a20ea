"""Files the lab's data live in: atomic whole-file writes, append-only records, folder locks.

One owner for the rules every package's data files follow (calibration readings, stimulus
manifests, session CSVs and slider histories, run logs, reports):

- a whole file is written atomically and fsynced, with the umask's permissions (:mod:`.atomic`);
- a record is appended the moment it exists, one line, fsynced; a torn tail is detected on every
  open, kept in a side file, cut back to the last whole record and reported (:mod:`.records`);
- a folder one run writes into is locked against a second run (:mod:`.lock`);
- a file another tool wrote (CRLF line ends, a BOM, UTF-16, quoted fields) is read as the
  project's own, and one in another form (``;``-separated, a Windows code page) is refused
  naming the fix (:mod:`.text`);
- an output folder is checked before a command's work, and a failed write is said in one line
  naming the file and the fix (:mod:`.outdir`).

It sits upstream of every package (it imports none of them), like ``studydesign``.
"""

from labfiles.atomic import (
    TEMPORARY_GLOB,
    atomic_open,
    atomic_path,
    atomic_write_bytes,
    atomic_write_text,
    fsync_dir,
    keep_owner_access,
    new_file_mode,
    temporary_path,
    write_new_file,
)
from labfiles.errors import LabFileError
from labfiles.lock import FolderLock, FolderLocked
from labfiles.records import (
    RecordFile,
    TornTail,
    TornTailWarning,
    append_csv_record,
    csv_fields_check,
    csv_record,
    find_torn_tail,
    json_record,
    json_record_check,
    read_csv_records,
    read_records,
    repair_torn_tail,
)
from labfiles.text import (
    SAVE_AS_UTF8,
    check_comma_separated,
    csv_separator,
    decode_text,
    read_csv_frame,
    read_text,
    read_toml,
    separator_message,
    text_encoding,
    utf8_records,
)

__all__ = [
    "SAVE_AS_UTF8",
    "TEMPORARY_GLOB",
    "FolderLock",
    "FolderLocked",
    "LabFileError",
    "RecordFile",
    "TornTail",
    "TornTailWarning",
    "append_csv_record",
    "atomic_open",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_comma_separated",
    "csv_fields_check",
    "csv_record",
    "csv_separator",
    "decode_text",
    "find_torn_tail",
    "fsync_dir",
    "json_record",
    "json_record_check",
    "new_file_mode",
    "read_csv_frame",
    "read_csv_records",
    "read_records",
    "read_text",
    "read_toml",
    "repair_torn_tail",
    "separator_message",
    "temporary_path",
    "text_encoding",
    "utf8_records",
    "write_new_file",
]

keep_owner_access()  # a umask denying the owner access: warned and relaxed, once
