"""The bearer token, read by the rule of wire/rpc/token.h, the same as epr, epr-master and epr-worker.

The whole file (or $EPR_TOKEN), with trailing white space removed; what remains must be non-empty
printable ASCII without spaces (it travels as "authorization: Bearer <token>" metadata). A file other
users can read or write is used with a warning (chmod 600 it).
"""

from __future__ import annotations

import logging
import os
import stat
from typing import Optional

from .errors import TokenError

log = logging.getLogger("eprfarm")


def is_valid_token(token: str) -> bool:
    """True for one token: non-empty printable ASCII without spaces."""
    return bool(token) and all(0x20 < ord(c) < 0x7F for c in token)


def _check_token(text: str, source: str) -> str:
    text = text.rstrip(" \t\n\v\f\r")
    if not text:
        raise TokenError(f"{source} is empty: it must hold the bearer token")
    if not is_valid_token(text):
        raise TokenError(
            f"{source} must hold one token of printable ASCII characters, without spaces or line breaks "
            "(only trailing white space is ignored)"
        )
    return text


def read_token_file(path: str) -> str:
    """The token held in `path`; TokenError if it cannot be read, is empty or is not one token."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError:
        raise TokenError(f"cannot read the token file '{path}'") from None
    token = _check_token(data.decode("latin-1"), f"the token file '{path}'")
    try:
        mode = os.stat(path).st_mode
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            log.warning("the token file '%s' is open to other users (mode %03o): chmod 600 it", path, mode & 0o777)
    except OSError:
        pass
    return token


def configured_token(token_file: Optional[str] = None) -> Optional[str]:
    """`token_file` if given, else $EPR_TOKEN if set and not empty (same rule), else None."""
    if token_file:
        return read_token_file(token_file)
    env = os.environ.get("EPR_TOKEN", "")
    if not env:
        return None
    return _check_token(env, "$EPR_TOKEN")
