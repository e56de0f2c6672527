"""Credentials of the Zenoh mesh: one user name and password per node identity.

Zenoh's user/password authentication (``transport.auth.usrpwd``): a node opening
a session sends its user name and a proof of its password over the router's
nonce; the router (the accepting side) checks them against its dictionary file
(``user:password`` per line) and refuses the session otherwise. The
authenticated user name is the identity the router's access-control list matches
(:mod:`services.io.acl`).

Identities (:data:`ROLES`) and their user names ``ssmpc-<role>``:

============  =============================================================
``plant``     the plant node (``ssmpc plant``, ``ssmpc opcua``)
``controller``  the controller node
``api``       the REST api node
``cli``       an operator's own session on the mesh (tools, bench, soak)
============  =============================================================

Layout of a credentials directory (``<state-dir>/mesh`` for ``ssmpc up``), the
directory owner-only (0700) and every file owner-only (0600):

``<role>.key``
    the role's password (a node host needs only its own);
``passwords``
    the router's dictionary, every role's ``ssmpc-<role>:<password>``.

They are made on first start and reused; :func:`make_credentials` with
``rotate=True`` draws new passwords (the router and every node must then be
restarted: Zenoh reads them when a session opens). A directory or file that is
missing, not a regular file, not the user's own, or readable or writable by
anyone else is refused with a ``ValueError`` naming ``credentials`` and the fix.
"""

from __future__ import annotations

import os
import secrets
import stat
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["ROLES", "USER_PREFIX", "DIRECTORY_NAME", "DICTIONARY_FILE", "NodeCredentials",
           "credentials_directory", "user_name", "make_credentials", "node_credentials",
           "router_dictionary"]

ROLES = ("plant", "controller", "api", "cli")
USER_PREFIX = "ssmpc-"
#: Name of the credentials directory inside a state directory.
DIRECTORY_NAME = "mesh"
DICTIONARY_FILE = "passwords"
#: Bytes of randomness per password (``secrets.token_urlsafe``: 43 characters of
#: ``[A-Za-z0-9_-]``, no ``:`` that would break the dictionary's format).
PASSWORD_BYTES = 32


def credentials_directory(state_dir: str | os.PathLike) -> Path:
    """``<state_dir>/mesh``: where ``ssmpc up`` keeps the mesh credentials."""
    return Path(state_dir) / DIRECTORY_NAME


def user_name(role: str) -> str:
    """The Zenoh user name of a role, ``ssmpc-<role>``."""
    _check_role(role)
    return USER_PREFIX + role


def _check_role(role: str) -> None:
    if role not in ROLES:
        raise ValueError(f"role: expected one of {ROLES}, got {role!r}")


@dataclass(frozen=True)
class NodeCredentials:
    """A node's identity on the mesh.

    Parameters
    ----------
    role : str
        One of :data:`ROLES`.
    password : str
        The role's password (not shown by ``repr``).
    """

    role: str
    password: str = field(repr=False)

    def __post_init__(self) -> None:
        _check_role(self.role)
        if not self.password or any(c in self.password for c in ":\r\n"):
            raise ValueError(f"credentials: the {self.role} password is empty or has ':' "
                             "or a line break")

    @property
    def user(self) -> str:
        return user_name(self.role)


def _check_private(path: Path, *, directory: bool) -> None:
    """Refuse ``path`` unless it is the user's own directory/regular file, owner-only."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        what = "directory" if directory else "file"
        raise ValueError(f"credentials: {what} {str(path)!r} does not exist; make the "
                         "credentials with 'ssmpc credentials --state-dir DIR'") from None
    except OSError as exc:
        raise ValueError(f"credentials: cannot read {str(path)!r}: {exc.strerror}") from None
    kind_ok = stat.S_ISDIR(st.st_mode) if directory else stat.S_ISREG(st.st_mode)
    if not kind_ok:
        want = "a directory" if directory else "a regular file"
        raise ValueError(f"credentials: {str(path)!r} is not {want} (symbolic links are "
                         "refused)")
    if st.st_uid != os.getuid():
        raise ValueError(f"credentials: {str(path)!r} belongs to uid {st.st_uid}, not to "
                         f"this user (uid {os.getuid()})")
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o077:
        want = "0700" if directory else "0600"
        raise ValueError(f"credentials: {str(path)!r} is open to others (mode {mode:04o}); "
                         f"it must be owner-only: chmod {want} {path}")


def _read_private(path: Path) -> str:
    _check_private(path, directory=False)
    try:
        return path.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise ValueError(f"credentials: cannot read {str(path)!r}: {reason}") from None


def _write_private(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` owner-only, atomically (a temporary file renamed)."""
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    try:
        with os.fdopen(fd, "w", encoding="ascii") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _key_file(directory: Path, role: str) -> Path:
    return directory / f"{role}.key"


def make_credentials(directory: str | os.PathLike, *, rotate: bool = False) -> list[str]:
    """Make the credentials in ``directory`` where missing (all of them with ``rotate``).

    The directory is created 0700; an existing one must already be owner-only.

    Returns
    -------
    list of str
        The roles whose password was made now (empty: all were reused).
    """
    directory = Path(directory)
    if not directory.exists():
        try:
            directory.mkdir(mode=0o700, parents=True)
        except OSError as exc:
            raise ValueError(f"credentials: cannot create {str(directory)!r}: "
                             f"{exc.strerror}") from None
        os.chmod(directory, 0o700)  # mkdir's mode is masked by the umask
    _check_private(directory, directory=True)
    made = []
    passwords = {}
    for role in ROLES:
        path = _key_file(directory, role)
        if rotate or not path.exists():
            passwords[role] = secrets.token_urlsafe(PASSWORD_BYTES)
            _write_private(path, passwords[role] + "\n")
            made.append(role)
        else:
            passwords[role] = node_credentials(directory, role).password
    dictionary = "".join(f"{user_name(r)}:{passwords[r]}\n" for r in ROLES)
    dict_path = directory / DICTIONARY_FILE
    if made or not dict_path.exists() or _read_private(dict_path) != dictionary:
        _write_private(dict_path, dictionary)
    return made


def node_credentials(directory: str | os.PathLike, role: str) -> NodeCredentials:
    """The credentials of ``role`` from ``directory`` (checked owner-only)."""
    _check_role(role)
    directory = Path(directory)
    _check_private(directory, directory=True)
    text = _read_private(_key_file(directory, role)).strip()
    return NodeCredentials(role=role, password=text)


def router_dictionary(directory: str | os.PathLike) -> Path:
    """The router's dictionary file in ``directory``, checked owner-only and well formed."""
    directory = Path(directory)
    _check_private(directory, directory=True)
    path = directory / DICTIONARY_FILE
    lines = _read_private(path).splitlines()
    users = [ln.split(":", 1)[0] for ln in lines if ln.strip()]
    if not users or any(":" not in ln for ln in lines if ln.strip()):
        raise ValueError(f"credentials: {str(path)!r} is not a dictionary of "
                         "'user:password' lines")
    return path
