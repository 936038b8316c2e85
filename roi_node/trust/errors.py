"""The trust folder's error classes: bad keys, signatures and policy files (exit 2), and a refused export (exit 2)."""

from __future__ import annotations

from pathlib import Path

from roi_node.engine.errors import ConfigError, InputDataError, UsageError


class PolicyFileError(ConfigError):
    """A sharing or trust policy file that is missing, not YAML, or has a key or value it may not have."""

    def __init__(self, path: Path, field: str, problem: str) -> None:
        super().__init__(f"{path}: {field}: {problem}")
        self.path = path
        self.field = field
        self.problem = problem


class KeyFileError(ConfigError):
    """A private key, public key or certificate file that is missing, malformed or of a kind model-signing cannot use."""

    def __init__(self, path: Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = path
        self.problem = problem


class SignatureFileError(InputDataError):
    """A signature file that is missing or is not a model-signing (Sigstore bundle) signature roi_node can read."""

    def __init__(self, path: Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = path
        self.problem = problem


class SigningError(InputDataError):
    """Signing could not be done: the data is not a bag or dataset, or the signing service could not be reached."""


class SharingRefusedError(UsageError):
    """Sessions whose sharing policy does not allow the dataset's audience (or whose licenses differ), named with why."""

    def __init__(self, message: str, refused: tuple[tuple[Path, str], ...]) -> None:
        super().__init__(message)
        self.refused = refused
