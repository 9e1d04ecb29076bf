"""Reading another logger's CSV (`adxlgw import`): the wanted columns' numbers, and their
line numbers, a block of rows at a time.

The file is streamed (the line length limit of recordings, UTF-8 checked); a time column
is kept relative to its first cell, exactly when the cells are integers; a cell that is
not a number, a missing column, a row cut short are each named by file and line.
"""
from __future__ import annotations

import csv
import math
import os
from array import array
from pathlib import Path

import numpy as np

from gateway.errors import RecordingError
from gateway.offline.progress import progress_bar
from gateway.offline.recording import MAX_LINE_BYTES, cell_text, line_blocks


def _number(cell: str, path: str, line: int, column: str):
    """Integers stay exact (nanosecond timestamps exceed float precision); others are floats."""
    try:
        return int(cell)
    except ValueError:
        pass
    try:
        value = float(cell)
    except ValueError:
        raise RecordingError(f"{path}:{line}: column {column!r}: {cell_text(cell)} is not a number") from None
    if not math.isfinite(value):
        raise RecordingError(f"{path}:{line}: column {column!r}: {cell_text(cell)} is not finite")
    return value


def _float(value, path: str, line: int, column: str, minus=0) -> float:
    """value − minus as a float: exact first when both are integers."""
    try:
        return float(value - minus)
    except OverflowError:  # an integer of hundreds of digits
        raise RecordingError(f"{path}:{line}: column {column!r}: {cell_text(str(value))} is not finite") from None


def _text_lines(path: str, bar, end: dict):
    """The file's lines as text (without their line ends), read a block at a time: the line
    length limit of recordings (MAX_LINE_BYTES), UTF-8 checked, named by its byte offset.
    end["cut"]: whether the last line has no line end (a file cut short?)."""
    for block, first_line, offset in line_blocks(path, path):
        end["cut"] = not block.endswith(b"\n")
        try:
            text = block.decode("utf-8")
        except UnicodeDecodeError as err:
            line = first_line + block.count(b"\n", 0, err.start)
            raise RecordingError(f"{path}:{line}: not UTF-8 text ({err.reason} at byte offset "
                                 f"{offset + err.start})") from None
        if offset == 0:
            text = text.removeprefix("\ufeff")  # a spreadsheet's byte-order mark is not part of the header
        lines = text.split("\n")
        if text.endswith("\n"):
            lines.pop()
        for line in lines:
            yield line[:-1] if line.endswith("\r") else line
        bar.update(len(block))


def _hint(cell: str, args, path: str, line: int) -> float:
    if cell == "":
        return float("nan")
    if cell == args.hint_rest_value:
        return 1.0
    if cell == args.hint_moving_value:
        return 0.0
    raise RecordingError(f"{path}:{line}: column {args.hint_col!r}: {cell!r} is neither the rest value "
                         f"{args.hint_rest_value!r} nor the moving value {args.hint_moving_value!r} "
                         "(empty = unknown)")


def _wanted(args) -> dict[str, str]:
    wanted = {"time": args.arrival_col or args.time_col, "acc": args.acc_col}
    optional = {"acc_y": args.acc_y_col, "temp": args.temp_col, "ref_pos": args.ref_pos_col,
                "ref_vel": args.ref_vel_col, "ref_acc": args.ref_acc_col, "hint": args.hint_col,
                "check": args.check_time_col}
    wanted.update({role: name for role, name in optional.items() if name})
    return wanted


class _Column:
    """One wanted column's numbers as compact doubles (8 bytes a row, not a Python object).
    A time column keeps each cell minus the first, computed exactly when both are integers
    (nanoseconds since 1970 exceed a double's precision), so it is seconds since the first
    row once scaled by its unit."""

    def __init__(self, relative: bool):
        self.values = array("d")
        self.relative = relative
        self.first = None  # the first cell of a relative column, as read (int or float)

    def numbers(self) -> np.ndarray:
        return np.frombuffer(self.values, dtype=float) if self.values else np.zeros(0)


#: Rows per block of the streamed import: the memory a block takes (a few MB), not the file's.
BLOCK_ROWS = 1 << 16


class _Skipped:
    rows = 0  # rows without a time or an acceleration, so far


def foreign_blocks(args, skipped: _Skipped, block_rows: int | None = None):
    """The wanted columns' numbers for rows with a time and an acceleration, and their line
    numbers, a block of `block_rows` (BLOCK_ROWS) rows at a time; the file streamed, with a
    progress bar."""
    block_rows = block_rows or BLOCK_ROWS
    path = args.foreign
    try:
        size = os.path.getsize(path)
    except OSError as err:
        raise RecordingError(f"{path}: cannot read: {err.strerror or err}") from err
    end = {"cut": False}
    # a quoted field running over many lines stops at the line limit too
    limit = csv.field_size_limit(MAX_LINE_BYTES)
    try:
        with progress_bar(size, f"reading {Path(path).name}") as bar:
            reader = csv.reader(_text_lines(path, bar, end), delimiter=args.delimiter)
            yield from _row_blocks(args, reader, end, skipped, block_rows)
    finally:
        csv.field_size_limit(limit)  # the process's setting, as it was


def read_foreign(args) -> tuple[dict[str, np.ndarray], np.ndarray, int]:
    """The whole file's numbers (foreign_blocks put together): what the re-timing needs."""
    skipped = _Skipped()
    blocks = list(foreign_blocks(args, skipped, block_rows=1 << 62))
    values, lines = blocks[0] if blocks else ({}, np.zeros(0, dtype=np.int64))
    return values, lines, skipped.rows


def _csv_error(path: str, reader, err: csv.Error) -> RecordingError:
    if "new-line character" in str(err):
        # lines end at \n: a lone \r (classic Mac line ends) is taken for a break inside a row
        return RecordingError(f"{path}:{reader.line_num}: a line break (\\r) inside a row; lines must end with "
                              "\\n or \\r\\n (a file with classic Mac line ends? convert them)")
    return RecordingError(f"{path}:{reader.line_num}: cannot be read as CSV: {err}")


def _row_blocks(args, reader, end: dict, skipped: _Skipped, block_rows: int):
    """The rows with a time and an acceleration, as blocks of `block_rows` (see _block)."""
    path = args.foreign
    header, index = _header_index(args, reader)
    wanted = _wanted(args)
    columns = {role: _Column(relative=role in ("time", "check")) for role in wanted}
    lines = array("q")
    last_cells = len(header)
    for row, line in _rows(reader, path):
        last_cells = len(row)
        cells = {role: (row[i].strip() if i < len(row) else "") for role, i in index.items()}
        if not cells["time"] or not cells["acc"]:
            skipped.rows += 1
            continue
        _append_cells(args, columns, cells, wanted, line)
        lines.append(line)
        if len(lines) >= block_rows:
            yield _block(columns, lines)
            lines = array("q")
    if end["cut"] and last_cells < len(header):
        # a logger killed mid-row (rows of fewer cells are fine elsewhere: other kinds of row)
        raise RecordingError(f"{path}:{reader.line_num}: has {last_cells} cells, the header has {len(header)} "
                             "(the last line is cut short: a truncated file?)")
    if lines:
        yield _block(columns, lines)


def _header_index(args, reader) -> tuple[list[str], dict[str, int]]:
    """The header row, and where each wanted column is in it; the missing ones named all at
    once, with the columns there are (and a hint at the delimiter)."""
    path = args.foreign
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise RecordingError(f"{path}:1: empty file, no header row") from None
    except csv.Error as err:
        raise _csv_error(path, reader, err) from None
    wanted = _wanted(args)
    missing = [name for name in wanted.values() if name not in header]
    if missing:
        shown = ", ".join(repr(h) for h in header[:20]) + (f", … ({len(header)} in all)" if len(header) > 20 else "")
        hint = ("; one column only, with ';' in it: a ';'-separated file? give --delimiter ';'"
                if len(header) == 1 and ";" in header[0] and args.delimiter != ";" else "")
        raise RecordingError(f"{path}:1: no column {', '.join(map(repr, missing))} in the header; "
                             f"its columns: {shown}{hint}")
    return header, {role: header.index(name) for role, name in wanted.items()}


def _rows(reader, path: str):
    """(cells, line number) of each non-empty row after the header; a CSV error names its line."""
    rows = iter(reader)
    while True:
        try:
            row = next(rows)
        except StopIteration:
            return
        except csv.Error as err:
            raise _csv_error(path, reader, err) from None
        if row:
            yield row, reader.line_num


def _append_cells(args, columns: dict[str, _Column], cells: dict[str, str], wanted: dict[str, str],
                  line: int) -> None:
    """One row's wanted cells onto their columns: the hint as 1/0/NaN, an empty cell as NaN,
    a time relative to the column's first cell, the rest as numbers."""
    path = args.foreign
    for role, cell in cells.items():
        column = columns[role]
        if role == "hint":
            column.values.append(_hint(cell, args, path, line))
        elif not cell:
            column.values.append(math.nan)
        elif column.relative:
            number = _number(cell, path, line, wanted[role])
            if column.first is None:
                column.first = number
            column.values.append(_float(number, path, line, wanted[role], minus=column.first))
        else:
            column.values.append(_float(_number(cell, path, line, wanted[role]), path, line, wanted[role]))


def _block(columns: dict[str, _Column], lines: array) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The rows gathered so far as arrays; the columns start the next block empty (a relative
    column keeps its first cell)."""
    values = {role: column.numbers() for role, column in columns.items()}
    for column in columns.values():
        column.values = array("d")
    return values, np.frombuffer(lines, dtype=np.int64)

