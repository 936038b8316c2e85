"""Why an action vector, an action name or a policy was refused: each names the joint, value or module at fault."""

from __future__ import annotations

from collections.abc import Sequence

from roi_node.engine.errors import ConfigError, InputDataError


class UnknownActionNameError(ConfigError):
    """An action name (from the dataset features or the policy) that no robot of the rig has as a JointState name."""

    def __init__(self, name: str, rig: str, known: Sequence[str]) -> None:
        shown = ", ".join(known[:8]) + (", ..." if len(known) > 8 else "")
        super().__init__(f"action name {name!r} is no joint of the rig {rig} (its JointState names: {shown})")
        self.name = name
        self.rig = rig
        self.known = tuple(known)


class ActionShapeError(InputDataError):
    """A policy output that is not a vector, chunk or mapping of the action's length; the policy and the features
    disagree. `returned` says what came back: a shape, or the kind of value where there is none (None, a string)."""

    def __init__(self, source: str, length: int, returned: str, shape: tuple[int, ...] | None = None) -> None:
        super().__init__(
            f"{source}: returned {returned}; expected ({length},) or a chunk (steps, {length}) of real numbers over the "
            f"{length} action names, or a mapping of each name to a number or a series of steps"
        )
        self.source = source
        self.shape = shape
        self.length = length
        self.returned = returned


class ActionNamesError(InputDataError):
    """A policy output given as a mapping whose joint names are not exactly the action names."""

    def __init__(self, source: str, missing: Sequence[str], unknown: Sequence[str]) -> None:
        parts = ([f"missing {', '.join(missing)}"] if missing else []) + ([f"unknown {', '.join(unknown)}"] if unknown else [])
        super().__init__(f"{source}: returned a mapping of joint names that is not the action's names: {'; '.join(parts)}")
        self.source = source
        self.missing = tuple(missing)
        self.unknown = tuple(unknown)


class NonFiniteActionError(InputDataError):
    """A policy output holding NaN or infinity: refused and counted, never published."""

    def __init__(self, source: str, joints: Sequence[str]) -> None:
        super().__init__(f"{source}: returned a non-finite action (NaN or inf) for {', '.join(joints)}; refused, not published")
        self.source = source
        self.joints = tuple(joints)


class PolicyLoadError(ConfigError):
    """A --policy that cannot be loaded: a module that does not import, a missing function, a pretrained dir without its files."""

    def __init__(self, policy: str, problem: str) -> None:
        super().__init__(f"--policy {policy}: {problem}")
        self.policy = policy
        self.problem = problem


def policy_did(error: BaseException) -> str:
    """What a policy did when it did not return, as a phrase: `called sys.exit(3)`, `raised GeneratorExit`, `raised
    ValueError: <its first line>`. The one place a policy's escape is named: a SystemExit, KeyboardInterrupt or
    GeneratorExit out of a policy (on import or per call) is its failure, classified like any exception, so it never
    becomes the process's exit status (0, 3, 130) or a traceback."""
    if isinstance(error, SystemExit):
        return f"called sys.exit({'' if error.code is None else repr(error.code)})"
    detail = str(error).splitlines()[0][:300] if str(error).strip() else ""
    return f"raised {type(error).__name__}{': ' + detail if detail else ''}"


class PolicyCallError(InputDataError):
    """The policy did not return while acting (it raised, or called sys.exit): the run stops, naming the policy,
    what it did and the frame."""

    def __init__(self, policy: str, stamp_ns: int, error: BaseException) -> None:
        super().__init__(f"--policy {policy}: {policy_did(error)} on the observation of frame {stamp_ns}")
        self.policy = policy
        self.stamp_ns = stamp_ns
        self.error = error
