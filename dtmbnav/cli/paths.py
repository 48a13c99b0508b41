"""A command line's files: outputs never name an input (exit 2); output places exist and are writable (exit 3).

Each command module says which of its options are inputs, file outputs and folder outputs (its
``io_paths``, set as the parser's default); this module checks them the same way for every command.
Inputs are checked by the readers, which name what is wrong with them.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

#: (option, path) pairs: an option's name (or its metavar) and the path it was given.
OptionPaths = list[tuple[str, str]]
#: A command's (inputs, file outputs, folder outputs).
IoPaths = tuple[OptionPaths, OptionPaths, OptionPaths]


def given_paths(inputs: list[tuple[str, object]] = (), files: list[tuple[str, object]] = (),
             folders: list[tuple[str, object]] = ()) -> IoPaths:
    """A command's :data:`IoPaths`, its options not given (None) left out, and ``-`` (stdin, stdout) left
    out of the inputs and the files."""
    def given(pairs, stream_allowed: bool) -> OptionPaths:
        return [(o, str(v)) for o, v in pairs if v is not None and not (stream_allowed and str(v) == "-")]
    return given(inputs, True), given(files, True), given(folders, False)


def same_path(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name one file (the same file through links where both exist)."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.exists() and pb.exists():
            return os.path.samefile(pa, pb)
    except OSError:
        pass
    return pa.resolve() == pb.resolve()


def check_usage(args: argparse.Namespace) -> str | None:
    """Usage errors argparse cannot see (the command's option combinations, outputs naming inputs); None when
    fine."""
    usage_problem = getattr(args, "usage_problem", None)
    if usage_problem is not None and (problem := usage_problem(args)):
        return problem
    if getattr(args, "output", None) is not None and str(args.output) == "-" and args.command in ("receive", "pdr",
                                                                                                  "fuse", "sensors"):
        hint = " (use --csv - for the rows)" if hasattr(args, "csv") else ""
        return f"-o -: an HDF5 file cannot be written to stdout{hint}"
    inputs, files, folders = args.io_paths(args)
    outputs = files + folders
    for out_option, out in outputs:
        for in_option, src in inputs:
            if same_path(out, src):
                return f"{out_option} {out} names the input {src} ({in_option}); choose another output path"
    for i, (option_a, a) in enumerate(outputs):
        for option_b, b in outputs[i + 1:]:
            if same_path(a, b):
                return f"{option_a} and {option_b} name the same path {a}"
    return None


def check_paths(args: argparse.Namespace) -> None:
    """Outputs that cannot be written (a folder as a file, a missing or non-folder parent): ValueError (exit 3).

    Inputs are checked by the readers, which name what is wrong with them.
    """
    _, files, folders = args.io_paths(args)
    for option, text in files:
        path = Path(text)
        if path.is_dir():
            raise ValueError(f"{option} {path}: is a folder; give a file name")
        if not path.parent.is_dir():
            raise ValueError(f"{option} {path}: folder {path.parent} does not exist" if not path.parent.exists()
                             else f"{option} {path}: {path.parent} is not a folder")
    for option, text in folders:
        path = Path(text)
        if path.exists() and not path.is_dir():
            raise ValueError(f"{option} {path}: exists and is not a folder")
        ancestor = path.parent
        while not ancestor.exists():
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise ValueError(f"{option} {path}: {ancestor} is not a folder")
