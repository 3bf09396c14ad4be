"""Logging for the command line: a handler that writes between progress bars, and a filter that says a
repeated message once."""

from __future__ import annotations

import logging
import sys


class BarSafeHandler(logging.Handler):
    """Log lines to stderr through tqdm, so that a message does not land on a progress bar's line."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm import tqdm

            # one write of the line and its newline: tqdm.write makes two, and a signal between them left
            # the interruption message on the end of the last log line
            with tqdm.external_write_mode(file=sys.stderr):
                sys.stderr.write(self.format(record) + "\n")
        except Exception:
            self.handleError(record)


class Repeats(logging.Filter):
    """Say a repeated message once. An identical one is dropped; one that differs only in its first
    argument, the file or view it is about ("%s: L image converted to RGB"), is counted, and the others
    it was said for are named together at the end (:meth:`rest`)."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: set[tuple[int, str]] = set()
        self.more: dict[tuple, tuple[logging.LogRecord, list[str]]] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if (record.levelno, text) in self.seen:
            return False
        self.seen.add((record.levelno, text))
        args = record.args if isinstance(record.args, tuple) else ()
        if not args or not str(record.msg).startswith("%s: "):  # "<file>: <what about it>"
            return True
        key = (record.levelno, record.msg, tuple(map(repr, args[1:])))
        if key not in self.more:
            self.more[key] = (record, [])
            return True
        self.more[key][1].append(str(args[0]))
        return False

    def rest(self) -> list[logging.LogRecord]:
        """One record per message said for more than one file, naming the others: '02.png, 03.png: ...', and
        past five '02.png, ..., 06.png and 2 more: ...' (the count is of the names not shown)."""
        out = []
        for rec, names in self.more.values():
            if names and isinstance(rec.args, tuple):  # always: only records with tuple args are counted
                who = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
                out.append(logging.makeLogRecord({**vars(rec), "msg": rec.msg % ((who,) + rec.args[1:]), "args": None}))
        return out
