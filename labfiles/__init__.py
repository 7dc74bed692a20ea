"""Files the lab's data live in: atomic whole-file writes, append-only records, folder locks.

One owner for the rules every package's data files follow (calibration readings, stimulus
manifests, session CSVs and slider histories, run logs, reports):

- a whole file is written atomically and fsynced, with the umask's permissions (:mod:`.atomic`);
- a record is appended the moment it exists, one line, fsynced; a torn tail is detected on every
  open, kept in a side file, cut back to the last whole record and reported (:mod:`.records`);
- a folder one run writes into is locked against a second run (:mod:`.lock`).
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
    new_file_mode,
    temporary_path,
    write_new_file,
)
from labfiles.lock import FolderLock, FolderLocked
from labfiles.records import (
    LabFileError,
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

__all__ = [
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
    "csv_fields_check",
    "csv_record",
    "find_torn_tail",
    "fsync_dir",
    "json_record",
    "json_record_check",
    "new_file_mode",
    "read_csv_records",
    "read_records",
    "repair_torn_tail",
    "temporary_path",
    "write_new_file",
]
