"""Role credentials made at run time, never kept in the repository.

A credentials directory holds the router's user-password dictionary `zenoh-users` ("user:password"
lines, zenoh's `transport/auth/usrpwd/dictionary_file`) and one password file `zenoh-<role>` per role
of `common.deploy.acl.ROLES`; the names are the compose secrets' names. Every file is readable by its owner
only. A service reads its role's file through FLEET_ZENOH_USER / FLEET_ZENOH_PASSWORD_FILE.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common.deploy.acl import ROLES, ROUTER_CONFIG

USERS_FILE = "zenoh-users"


@dataclass(frozen=True)
class Credentials:
    """A credentials directory (see the module docstring)."""

    dir: Path

    @property
    def users_file(self) -> Path:
        return self.dir / USERS_FILE

    def password_file(self, role: str) -> Path:
        return self.dir / f"zenoh-{role}"

    def password(self, role: str) -> str:
        return self.password_file(role).read_text().strip()

    def env(self, role: str) -> dict[str, str]:
        """The environment a process of `role` gets."""
        return {"FLEET_ZENOH_USER": role, "FLEET_ZENOH_PASSWORD_FILE": str(self.password_file(role))}

    def options(self, role: str) -> dict[str, Any]:
        """`ZenohConfig` options of a session of `role`."""
        return {"user": role, "password": self.password(role)}

    def router_options(self) -> dict[str, Any]:
        """`ZenohConfig` options of a router enforcing the shipped access control with these users."""
        return {"config_file": str(ROUTER_CONFIG), "users_file": str(self.users_file)}

    def complete(self, roles: Iterable[str]) -> bool:
        return self.users_file.exists() and all(self.password_file(r).exists() for r in roles)


def _write_private(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


def make_credentials(directory: Path, roles: Iterable[str] = ROLES) -> Credentials:
    """Fresh random passwords for every role, written into `directory` (created, owner-only)."""
    directory.mkdir(parents=True, exist_ok=True, mode=0o700)
    creds = Credentials(directory)
    passwords = {role: secrets.token_urlsafe(24) for role in roles}
    for role, password in passwords.items():
        _write_private(creds.password_file(role), password + "\n")
    _write_private(creds.users_file, "".join(f"{role}:{pw}\n" for role, pw in passwords.items()))
    return creds


def ensure_credentials(directory: Path, roles: Iterable[str] = ROLES) -> Credentials:
    """The credentials in `directory`, made first if any file is missing."""
    roles = list(roles)
    creds = Credentials(directory)
    return creds if creds.complete(roles) else make_credentials(directory, roles)
