"""``python -m experiment run``'s end: what a run's outcome says on stderr, and its exit
status (:func:`main_run`)."""

from __future__ import annotations

import errno
import signal
import sys

__all__ = ["main_run"]


def main_run(req) -> int:
    """Run a session for the command line: messages on stderr, exit status.

    Returns 0 (complete or already complete), 1 (a write failed: a full disk, a read-only
    folder; everything recorded before is kept), 2 (a pre-flight or display problem: nothing
    was shown), 3 (quit by the operator), 130 (Ctrl-C); after 1, 3 and 130 the same command
    continues the session.
    """
    from experiment.checks import PreflightError
    from experiment.display import DisplayError
    from experiment.session import run_session
    from experiment.signals import SessionSignal
    from labfiles import LabFileError

    again = "run the same command to continue"
    try:
        res = run_session(req)
    except (PreflightError, DisplayError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        how, rc = (f"ended by {exc.name}", 128 + exc.signum) if isinstance(exc, SessionSignal) \
            else ("interrupted (Ctrl-C)", 130)
        print(f"{how}; every answered trial is kept in {req.data_dir}; {again}", file=sys.stderr)
        return rc
    except LabFileError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            what = (str(exc.strerror).split("; free space")[0]  # said once, below
                    if "disk is full" in str(exc.strerror)
                    else f"the disk is full: could not write {exc.filename or req.data_dir}")
            print(f"error: {what}. The trials answered so far are kept in {req.data_dir}; "
                  f"free space, then {again}", file=sys.stderr)
        elif exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
            print(f"error: cannot write {exc.filename or req.data_dir} ({exc.strerror}); the "
                  f"trials answered so far are kept; make the data folder writable, then "
                  f"{again}", file=sys.stderr)
        else:
            print(f"error: {exc}; the trials answered so far are kept in {req.data_dir}",
                  file=sys.stderr)
        return 1
    kept = (f"{res.trials_done} of {res.trials_total} trials are saved in {res.data_file}; "
            f"{again} (--data {req.data_dir})")
    if res.status == "quit":
        print(f"session {res.session} of {res.participant} paused: {kept}", file=sys.stderr)
        return 3
    if res.status == "interrupted" and res.signal:
        print(f"ended by {res.signal} (a shutdown, a closed terminal or kill): {kept}; the run's "
              f"log: {res.log_file}", file=sys.stderr)
        return 128 + int(getattr(signal, res.signal))
    if res.status == "interrupted":
        print(f"interrupted (Ctrl-C): {kept}", file=sys.stderr)
        return 130
    if res.status == "complete":
        log = (f"log {res.log_file}" if res.log_file is not None else
               "its run log could not be written (see the warning above; the trials are all "
               "kept, the log's timing and dropped-frame figures are not)")
        late = res.signal_after_last_answer
        late = (f" ({'Ctrl-C' if late == 'SIGINT' else late} came after the last answer: the "
                "run's log and end were recorded first)" if late else "")
        print(f"session {res.session} of {res.participant} complete: {res.trials_total} trials "
              f"in {res.data_file}; {log}{late}")
    return 0
