"""Secrets kept out of logs and API answers: the passwords of URLs.

Broker, result-backend and database URLs carry their server's password
(``redis://:secret@redis:6379/0``); an error message may quote one too. Everything the service
logs or reports about a URL passes through ``redact_url`` or ``redact_urls`` first."""

from __future__ import annotations

import re
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

MASK = "***"
"""What a password is replaced with."""

SECRET_QUERY_KEYS = frozenset({"password", "passwd", "pwd", "secret", "token"})
"""Query parameters that carry a password (``redis://host?password=...``)."""

_USERINFO = re.compile(r"(?P<scheme>[A-Za-z][A-Za-z0-9+.\-]*://)(?P<user>[^\s:/@]*):[^\s/@]*@")
_QUERY_SECRET = re.compile(
    r"(?P<key>[?&](?:" + "|".join(sorted(SECRET_QUERY_KEYS)) + r")=)[^&\s#]*", re.IGNORECASE
)


def redact_url(url: str) -> str:
    """``url`` with its password (user info and secret query parameters) masked; the scheme,
    user, host, port and path stay readable. Text that is no URL comes back unchanged."""
    try:
        parts = urlsplit(url)
    except ValueError:
        return redact_urls(url)
    netloc = parts.netloc
    userinfo, at, host = netloc.rpartition("@")
    if at and ":" in userinfo:
        netloc = f"{userinfo.split(':', 1)[0]}:{MASK}@{host}"
    query = parts.query
    if query:
        pairs = parse_qsl(query, keep_blank_values=True)
        if any(key.lower() in SECRET_QUERY_KEYS for key, _ in pairs):
            masked = [(k, MASK if k.lower() in SECRET_QUERY_KEYS else v) for k, v in pairs]
            query = urlencode(masked, safe="*")
    if (netloc, query) == (parts.netloc, parts.query):
        return url
    return urlunsplit((parts.scheme, netloc, parts.path, query, parts.fragment))


def redact_urls(text: str) -> str:
    """``text`` (an error message, say) with the password of every URL in it masked."""
    text = _USERINFO.sub(lambda m: f"{m['scheme']}{m['user']}:{MASK}@", text)
    return _QUERY_SECRET.sub(lambda m: f"{m['key']}{MASK}", text)
