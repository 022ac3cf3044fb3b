"""Lens profiles: which correction model belongs to which lens.

A correction model is learned for one lens design, and sharpening a capture
of another lens with it is wrong. A *profile* pairs a lens identity, read
from the file, with the correction model made for that lens; the
``correction`` stage runs the model of the profile that matches the frame
(:func:`match_profile`), and nothing where none does.

The identity
------------
Four strings of the file's metadata (:class:`isp.meta.CameraMeta`), named by
their DNG tags (Adobe, *Digital Negative Specification* 1.7.1.0, chapter 4;
LensModel is the EXIF 2.32 tag 0xA434 that DNG files carry in IFD 0 or the
EXIF IFD):

=====================  =============================  ======================
key                    CameraMeta field               example
=====================  =============================  ======================
``UniqueCameraModel``  ``unique_camera_model``        ``GoPro HERO6 Black``
``Make``               ``make``                       ``GoPro``
``Model``              ``model``                      ``HERO6 Black``
``LensModel``          ``lens``                       ``US-12210142-B2-e9``
=====================  =============================  ======================

The project's simulator (:mod:`calibration.simulate.capture`) and demo write
the identity of the lens they simulate, so their captures find their
profile as a phone's DNG would.

Profile files
-------------
A profile is a small TOML file (schema ``profile/v1``)::

    schema = "profile/v1"
    name = "e9"                       # default: the file's stem
    description = "the default phone lens, US-12210142-B2 embodiment 9"
    model = "e9_default.int8.onnx"    # the ONNX correction model, relative to this file
    device_model = "e9_device.int8.onnx"  # optional: a model conditioned on a module's calibration
    basis = "e9_basis.npz"            # optional: the descriptor basis its calibrations are written on
    # device = "module_0042.json"     # optional: one calibrated module's device/v1 file

    [match]
    LensModel = ["US-12210142-B2-e9", "US-12210142-B2-e9 (*)"]

A profile with a ``device_model`` corrects a module whose calibration is
known (``--device FILE``, the capture's own, or the profile's ``device``)
with that model, and every other capture of the lens with ``model``, the
blind one. Its ``basis`` is what ``isp calib fit`` and ``isp calib loop``
write a module's ``device.json`` on (:func:`calibration.fit.device.find_basis`).

``[match]`` holds one or more identity keys. A key's value is a pattern or
a list of patterns, any of which may match; every key given must match. A
pattern without ``*``, ``?`` or ``[`` is compared exactly, one with them is a
shell-style glob (:func:`fnmatch.fnmatchcase`); both are case-sensitive and
compared with the file's value stripped of surrounding white space (an
absent tag is the empty string, which only ``""`` or ``"*"`` match).

Several profiles matching
-------------------------
The most specific wins: the one matching more keys; then more keys matched
exactly rather than by a glob; then more literal characters in the patterns
that matched. Among equals, a profile of the user folder wins over one
registered in code, then one of a plug-in, then a packaged one; then the
first name in sorted order. The correction stage names the winner and the
others in its note (``isp process -v``).

Where profiles come from
------------------------
* packaged: the entry-point group ``isp.profiles`` of this project's own
  distribution (``phone-isp``): the default phone lens's profile lives next
  to its model in ``modules/models/``;
* plug-ins: the same group of any other installed distribution, e.g. in its
  ``pyproject.toml``::

      [project.entry-points."isp.profiles"]
      my_lens = "my_package.models:MY_LENS"

  where ``MY_LENS`` is a :class:`Profile`, the path of a profile file, or a
  function of no arguments returning either;
* the user folder: every ``*.toml`` file in ``$ISP_PROFILES`` (folders
  separated by ``os.pathsep``), else ``$XDG_CONFIG_HOME/phone-isp/profiles``
  (``~/.config/phone-isp/profiles``). A user profile named like another
  replaces it;
* code: :func:`register_profile` (a notebook, a test).

A profile that cannot be read (not TOML, a key it does not know, a model
file that is not there) is recorded with the reason in one line
(:func:`broken_profiles`, ``isp profiles``) and never stops the others.

``isp profiles`` lists them all; ``isp info FILE`` says which one matches a
file, or why none does.
"""

from __future__ import annotations

import fnmatch
import os
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

from isp.errors import ConfigError, InputError
from isp.registry import Registry

#: the schema a profile file declares
SCHEMA = "profile/v1"
#: the identity keys a profile may match on (DNG tag names), in reporting order
IDENTITY_KEYS = ("UniqueCameraModel", "Make", "Model", "LensModel")
#: the CameraMeta field of each identity key
META_FIELDS = {"UniqueCameraModel": "unique_camera_model", "Make": "make", "Model": "model",
               "LensModel": "lens"}
ENTRY_POINT_GROUP = "isp.profiles"
#: this project's distribution: its entry points are the packaged profiles
DISTRIBUTION = "phone-isp"
#: environment variable naming the user profile folder(s)
ENV_VAR = "ISP_PROFILES"
#: origins, the later winning a tie of specificity
ORIGINS = ("packaged", "plug-in", "code", "user")
#: profiles a no-match reason lists by name and identity
LISTED = 5
_GLOB = set("*?[")
_FILE_KEYS = {"schema", "name", "description", "model", "match", "demosaic", "device", "device_model", "basis"}


@dataclass(frozen=True)
class Profile:
    """A lens identity and the correction model made for that lens.

    Parameters
    ----------
    name : str
        What ``isp profiles`` and the stage's note call it.
    match : mapping of str to str or sequence of str
        Identity key (:data:`IDENTITY_KEYS`) → pattern(s); every key must
        match, any of a key's patterns may (module docstring).
    model : path
        The ONNX correction model (``isp export``).
    description : str
        One line for people.
    source : str
        The file the profile was read from ("" for one made in code).
    demosaic : str, optional
        The demosaic method the model was trained after (a name of
        :data:`modules.demosaic.METHODS`): the ``demosaic`` stage's
        ``method="auto"`` uses it for this lens, so that the correction sees
        the input it learnt from. None: the stage's own choice.
    device : path, optional
        A calibrated module's ``device/v1`` file (:mod:`isp.io.device`), for
        a model conditioned on the device: a profile that matches one module
        (its UniqueCameraModel or serial-bearing Model) carries its
        calibration; a capture's own (DNGPrivateData) and ``--device`` win.
    device_model : path, optional
        A model conditioned on a module's calibration, for the same lens:
        the stage runs it instead of ``model`` where a calibration is known.
    basis : path, optional
        The descriptor basis (``isp calib basis``) the conditioned model's
        calibrations are written on.

    Examples
    --------
    >>> p = Profile("e9", {"LensModel": "US-12210142-B2-e9*"}, "e9.onnx")
    >>> p.match
    {'LensModel': ('US-12210142-B2-e9*',)}
    >>> p.specificity({"LensModel": "US-12210142-B2-e9 (perturbed)"})
    (1, 0, 17)
    >>> p.specificity({"LensModel": "GoPro"}) is None
    True
    """

    name: str
    match: Mapping[str, Any]
    model: Path
    description: str = ""
    source: str = ""
    demosaic: str | None = None
    device: Path | None = None
    device_model: Path | None = None
    basis: Path | None = None

    def __post_init__(self):
        if not self.name or not isinstance(self.name, str):
            raise ConfigError(f"a profile needs a name, got {self.name!r}")
        if not isinstance(self.match, Mapping) or not self.match:
            raise ConfigError(f"profile {self.name!r}: 'match' must name at least one of "
                              f"{', '.join(IDENTITY_KEYS)}")
        match = {}
        for key, value in self.match.items():
            if key not in IDENTITY_KEYS:
                raise ConfigError(f"profile {self.name!r}: unknown identity key {key!r}; "
                                  f"valid: {', '.join(IDENTITY_KEYS)}")
            patterns = (value,) if isinstance(value, str) else value
            if (not isinstance(patterns, (list, tuple)) or not patterns
                    or not all(isinstance(p, str) for p in patterns)):
                raise ConfigError(f"profile {self.name!r}: {key} must be a string or a list of "
                                  f"strings, got {value!r}")
            match[key] = tuple(p.strip() for p in patterns)
        object.__setattr__(self, "match", match)
        if not isinstance(self.model, (str, os.PathLike)) or not str(self.model):
            raise ConfigError(f"profile {self.name!r}: 'model' must be a path, got {self.model!r}")
        object.__setattr__(self, "model", Path(self.model))
        for key in ("device", "device_model", "basis"):
            if getattr(self, key) is not None:
                object.__setattr__(self, key, Path(getattr(self, key)))

    def specificity(self, identity: Mapping[str, str]) -> tuple[int, int, int] | None:
        """How specifically the profile matches ``identity`` (key → value):
        ``(keys, exact keys, literal characters)`` of the patterns that
        matched, larger is more specific; None when a key does not match."""
        exact = chars = 0
        for key, patterns in self.match.items():
            value = (identity.get(key) or "").strip()
            hits = [p for p in patterns if _matches(p, value)]
            if not hits:
                return None
            best = max(hits, key=lambda p: (not _is_glob(p), _literal(p)))
            exact += not _is_glob(best)
            chars += _literal(best)
        return (len(self.match), exact, chars)

    def describe_match(self) -> str:
        """The identity it matches, one line: ``LensModel 'a' | 'b*'``."""
        return ", ".join(f"{k} " + " | ".join(repr(p) for p in v) for k, v in self.match.items())

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (``isp profiles --json``)."""
        return {"name": self.name, "match": {k: list(v) for k, v in self.match.items()},
                "model": str(self.model), "description": self.description, "source": self.source,
                **{k: str(getattr(self, k)) for k in ("device", "device_model", "basis")
                   if getattr(self, k) is not None}}


def _is_glob(pattern: str) -> bool:
    return bool(_GLOB & set(pattern))


def _literal(pattern: str) -> int:
    return sum(c not in _GLOB for c in pattern)


def _matches(pattern: str, value: str) -> bool:
    return fnmatch.fnmatchcase(value, pattern) if _is_glob(pattern) else value == pattern


def identity(meta: Any) -> dict[str, str]:
    """The lens identity of a capture: :data:`IDENTITY_KEYS` → the value of
    ``meta`` (a :class:`isp.meta.CameraMeta`, or any object with its
    fields), stripped; "" for an absent tag.

    >>> from isp.meta import CameraMeta
    >>> identity(CameraMeta(make="GoPro", model="HERO6 Black"))
    {'UniqueCameraModel': '', 'Make': 'GoPro', 'Model': 'HERO6 Black', 'LensModel': ''}
    """
    return {k: str(getattr(meta, f, "") or "").strip() for k, f in META_FIELDS.items()}


def describe_identity(ident: Mapping[str, str]) -> str:
    """One line: ``UniqueCameraModel 'GoPro HERO6 Black', ..., no LensModel``."""
    return ", ".join(f"{k} {ident[k]!r}" if ident.get(k) else f"no {k}" for k in IDENTITY_KEYS)


def read_profile(path: str | os.PathLike) -> Profile:
    """Read a profile file (module docstring); the model path is made
    absolute relative to the file and must exist.

    Raises
    ------
    InputError
        One line naming the file: unreadable, not TOML, another schema, an
        unknown key, a bad ``[match]``, a missing model file.
    """
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise InputError(path, f"cannot read profile: {e.strerror or e}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(path, f"not a TOML profile: {e}") from None
    schema = doc.get("schema", SCHEMA)
    if schema != SCHEMA:
        raise InputError(path, f"schema {schema!r}; this reader knows {SCHEMA!r}")
    unknown = sorted(set(doc) - _FILE_KEYS)
    if unknown:
        raise InputError(path, f"unknown key(s) {', '.join(unknown)}; valid: {', '.join(sorted(_FILE_KEYS))}")
    if "model" not in doc or "match" not in doc:
        missing = [k for k in ("model", "match") if k not in doc]
        raise InputError(path, f"a profile needs {' and '.join(missing)}")
    model = doc["model"]
    if not isinstance(model, str) or not model:
        raise InputError(path, f"'model' must be a file name, got {model!r}")
    model_path = Path(model).expanduser()
    if not model_path.is_absolute():
        model_path = path.parent / model_path
    if not model_path.is_file():
        raise InputError(path, f"model file {str(model_path)!r} not found")
    files = {key: _profile_file(path, doc, key, what) for key, what in (
        ("device", "device calibration file"), ("device_model", "device model file"), ("basis", "basis file"))}
    try:
        demosaic = doc.get("demosaic")
        if demosaic is not None and (not isinstance(demosaic, str) or not demosaic):
            raise InputError(path, f"'demosaic' must be a method name, got {demosaic!r}")
        return Profile(name=str(doc.get("name") or path.stem), match=doc["match"], model=model_path,
                       description=str(doc.get("description", "")), source=str(path), demosaic=demosaic,
                       **files)
    except ConfigError as e:
        raise InputError(path, str(e)) from None


def _profile_file(path: Path, doc: dict, key: str, what: str) -> Path | None:
    """The profile's optional file ``key``, relative to the profile; one
    line naming the profile where it is not a name or not there."""
    name = doc.get(key)
    if name is None:
        return None
    if not isinstance(name, str) or not name:
        raise InputError(path, f"'{key}' must be a file name, got {name!r}")
    found = Path(name).expanduser()
    found = found if found.is_absolute() else path.parent / found
    if not found.is_file():
        raise InputError(path, f"{what} {str(found)!r} not found")
    return found


def _check_entry(name: str, obj: Any) -> Profile:
    """What an ``isp.profiles`` entry point gives, as a Profile named like
    the entry point: a Profile, a profile file's path, or a function of no
    arguments returning either."""
    if callable(obj) and not isinstance(obj, (Profile, os.PathLike)):
        obj = obj()
    if isinstance(obj, (str, os.PathLike)):
        obj = read_profile(obj)
    if not isinstance(obj, Profile):
        raise TypeError(f"{type(obj).__name__}, not an isp.profiles.Profile or a profile file")
    return obj if obj.name == name else replace(obj, name=name)


#: every profile by name (packaged and plug-ins through entry points; user and code ones added)
PROFILES = Registry("profile", ENTRY_POINT_GROUP, check=_check_entry)
_user: dict[str, Any] = {"loaded": False, "names": set(), "broken": {}}


def user_folders() -> tuple[Path, ...]:
    """The folders user profiles are read from: ``$ISP_PROFILES`` (several
    separated by ``os.pathsep``), else ``$XDG_CONFIG_HOME/phone-isp/profiles``
    (default ``~/.config/phone-isp/profiles``). They need not exist."""
    env = os.environ.get(ENV_VAR)
    if env:
        return tuple(Path(p).expanduser() for p in env.split(os.pathsep) if p)
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return (Path(base) / "phone-isp" / "profiles",)


def _load_user() -> None:
    if _user["loaded"]:
        return
    _user["loaded"] = True
    for folder in user_folders():
        for f in sorted(folder.glob("*.toml")) if folder.is_dir() else ():
            try:
                p = read_profile(f)
            except InputError as e:   # one bad file must not hide the others
                _user["broken"][str(f)] = e.reason
                continue
            PROFILES.add(p.name, p, f"user ({f})")
            _user["names"].add(p.name)


def register_profile(profile: Profile) -> Profile:
    """Register ``profile`` (origin ``code``); re-registering a name
    replaces the entry. Returns it."""
    _load_user()
    return PROFILES.add(profile.name, profile, "code")


def reload_profiles() -> None:
    """Read the user folder and the entry points again (after a profile file
    was added or ``$ISP_PROFILES`` changed); profiles registered in code
    stay."""
    for name in _user["names"]:
        PROFILES.remove(name)
    _user.update(loaded=False, names=set(), broken={})
    PROFILES.reload()


def list_profiles() -> dict[str, Profile]:
    """Every profile by name, sorted."""
    _load_user()
    return PROFILES.entries()


def profile_origin(name: str) -> str:
    """Where a profile comes from: ``packaged``, ``plug-in``, ``user`` or
    ``code`` (:data:`ORIGINS`)."""
    _load_user()
    where = PROFILES.origin(name)
    if where.startswith("user ("):
        return "user"
    if where == "code":
        return "code"
    return "packaged" if where.split(" (", 1)[0] == DISTRIBUTION else "plug-in"


def profile_source(name: str) -> str:
    """Where exactly: the user file, or ``distribution (module:object)``."""
    _load_user()
    return PROFILES.origin(name)


def broken_profiles() -> dict[str, str]:
    """Profiles that could not be read, each with the reason in one line:
    user files by path, entry points by name."""
    _load_user()
    return {**_user["broken"], **PROFILES.broken()}


def get_profile(name: str) -> Profile:
    """The profile registered as ``name`` (ConfigError listing the valid names)."""
    _load_user()
    return PROFILES.get(name)


@dataclass(frozen=True)
class ProfileMatch:
    """What :func:`match_profile` found for one capture.

    Attributes
    ----------
    identity : dict
        The capture's identity (:func:`identity`).
    matching : tuple of Profile
        Every profile that matches, most specific first.
    profiles : tuple of str
        The names of every profile considered.
    broken : int
        How many profiles could not be read.
    described : mapping
        Name → what the profile matches (:meth:`Profile.describe_match`).
    """

    identity: dict[str, str]
    matching: tuple[Profile, ...]
    profiles: tuple[str, ...]
    broken: int = 0
    described: Mapping[str, str] = field(default_factory=dict)

    @property
    def profile(self) -> Profile | None:
        """The winner, or None."""
        return self.matching[0] if self.matching else None

    def reason(self) -> str:
        """One line: which profile matched and on what (and the others that
        matched too), or why none did: the identity and the profiles there
        are, with what each matches (the first :data:`LISTED`)."""
        p = self.profile
        if p is None:
            lens = self.identity.get("LensModel")
            if lens:
                others = {k: v for k, v in self.identity.items() if k != "LensModel" and v}
                text = f"no profile for LensModel {lens!r}"
                text += f" ({', '.join(f'{k} {v!r}' for k, v in others.items())})" if others else ""
            else:
                text = f"no profile for {describe_identity(self.identity)}"
            shown = [f"{n} ({self.described.get(n, '?')})" for n in self.profiles[:LISTED]]
            more = len(self.profiles) - LISTED
            text += "; profiles: " + (", ".join(shown) if shown else "none")
            text += f" and {more} more (`isp profiles`)" if more > 0 else ""
        else:
            on = ", ".join(f"{k} {self.identity.get(k, '')!r}" for k in p.match)
            text = f"profile {p.name!r} ({on})"
            if len(self.matching) > 1:
                text += (f"; the most specific of {len(self.matching)} matching: "
                         + ", ".join(q.name for q in self.matching))
        if self.broken:
            text += f"; {self.broken} profile(s) unreadable (see `isp profiles`)"
        return text

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (``isp info``)."""
        p = self.profile
        return {"profile": p.name if p else None, "model": str(p.model) if p else None,
                "identity": dict(self.identity), "matching": [q.name for q in self.matching],
                "reason": self.reason()}


def match_profile(meta: Any, profiles: Mapping[str, Profile] | None = None) -> ProfileMatch:
    """The profile of a capture's lens (module docstring: "Several profiles
    matching").

    Parameters
    ----------
    meta : CameraMeta or mapping
        The capture's metadata, or its identity (key → value).
    profiles : mapping of name to Profile, optional
        Default: every registered profile (:func:`list_profiles`).

    Examples
    --------
    >>> ps = {"any": Profile("any", {"LensModel": "e9*"}, "a.onnx"),
    ...       "e9": Profile("e9", {"LensModel": "e9"}, "b.onnx")}
    >>> m = match_profile({"LensModel": "e9"}, ps)
    >>> m.profile.name, [p.name for p in m.matching]
    ('e9', ['e9', 'any'])
    >>> match_profile({"Make": "GoPro"}, ps).profile is None
    True
    """
    ident = ({k: str(meta.get(k, "") or "").strip() for k in IDENTITY_KEYS}
             if isinstance(meta, Mapping) else identity(meta))
    broken = 0
    if profiles is None:
        profiles = list_profiles()
        broken = len(broken_profiles())
    scored = []
    for name, p in profiles.items():
        s = p.specificity(ident)
        if s is not None:
            rank = ORIGINS.index(profile_origin(name)) if name in PROFILES else ORIGINS.index("code")
            scored.append(((s, rank), name, p))
    scored.sort(key=lambda t: (tuple(-v for v in t[0][0]), -t[0][1], t[1]))
    described = {n: p.describe_match() for n, p in profiles.items()}
    return ProfileMatch(ident, tuple(p for _, _, p in scored), tuple(profiles), broken, described)
