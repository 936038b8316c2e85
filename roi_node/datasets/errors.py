"""The export's own error classes (RoiNodeErrors, so the CLI prints each as one line and exits 2)."""

from __future__ import annotations

from pathlib import Path

from roi_node.engine.errors import BagError, BagWriteError, UsageError


class DatasetError(BagError):
    """A dataset output exists without --append, is not a roi_node LeRobot export, or an episode does not fit it."""


class DatasetFileError(DatasetError):
    """A file of an existing dataset (what an append reads) is unreadable, or a field in it is not what LeRobot writes."""

    def __init__(self, path: Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = path
        self.problem = problem


class DatasetWriteError(DatasetError, BagWriteError):
    """A dataset file cannot be written (disk full, I/O error).

    pyarrow's and Python's write errors carry no file name, so the writer
    names the file: `file` is where it goes in the dataset `dataset`, which the
    failed export leaves as it was (its temporary folder is removed).
    """

    def __init__(self, dataset: Path, file: str, reason: str) -> None:
        super().__init__(f"{dataset / file}: cannot be written ({reason}); {dataset} is left as it was")
        self.dataset = dataset
        self.file = file
        self.reason = reason


class FrameGapError(BagError):
    """A grid time of a bag's episode with no frame within max_age before it nor the tolerance after it.

    Its own class so that `export lerobot --skip-gaps` can leave that bag out (naming it and `problem`) and export the
    others; `frame_index` is the first grid frame that has no frame to show.
    """

    def __init__(self, where: str, frame_index: int, problem: str) -> None:
        super().__init__(f"{where}: {problem}")
        self.where = where
        self.frame_index = frame_index
        self.problem = problem


class ExportOptionError(UsageError):
    """An export option whose value is out of its range or unusable (the API's counterpart of argparse's checks)."""

    def __init__(self, option: str, problem: str) -> None:
        super().__init__(f"{option}: {problem}")
        self.option = option
        self.problem = problem
