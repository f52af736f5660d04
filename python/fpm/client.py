"""A client of the acquisition service (``fpm serve``), standard library only.

>>> import fpm
>>> c = fpm.Client()                      # 127.0.0.1:8737, the token found by itself
>>> job = c.acquire("/data/field-1", reconstruct=True)
>>> for event in c.events():             # state changes and progress, as they happen
...     print(event)
...     if event.get("job") == job and event.get("state") in ("done", "failed", "cancelled"):
...         break
>>> c.job(job)["summary"]["frames_in_dataset"]
441

Requests that change the rig carry the token the service wrote (0600) into its state
directory; a refused request raises ``ServiceError`` with the service's message, which
names the field, header or job at fault.
"""

from __future__ import annotations

import json
import os
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Iterator, Optional

DEFAULT_ADDRESS = "127.0.0.1:8737"
FINAL_STATES = ("done", "failed", "cancelled", "interrupted")


class ServiceError(RuntimeError):
    """The service refused a request: ``status`` is the HTTP status, the message the
    service's own."""

    def __init__(self, status: int, message: str):
        super().__init__(f"{status}: {message}")
        self.status = status


def default_state_dir() -> Path:
    """Where ``fpm serve`` keeps its state unless told otherwise."""
    state = os.environ.get("XDG_STATE_HOME")
    return (Path(state) if state else Path.home() / ".local" / "state") / "fpm"


class Client:
    """The service at ``address`` (``host:port``); the token is read from
    ``state_dir`` (the service's ``--state-dir``) unless given."""

    def __init__(
        self,
        address: str = DEFAULT_ADDRESS,
        *,
        token: Optional[str] = None,
        state_dir: Optional[os.PathLike] = None,
        timeout: float = 30.0,
    ):
        self.address = address
        self.timeout = timeout
        if token is None:
            path = Path(state_dir) if state_dir is not None else default_state_dir()
            try:
                token = (path / "token").read_text().strip()
            except OSError:
                token = None  # reads still work; changes are refused, saying why
        self._token = token

    def _request(self, method: str, path: str, body: Any = None) -> Any:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(
            f"http://{self.address}{path}", data=data, method=method
        )
        if data is not None:
            request.add_header("Content-Type", "application/json")
        if method != "GET" and self._token:
            request.add_header("Authorization", f"Bearer {self._token}")
        try:
            with urllib.request.urlopen(request, timeout=self.timeout) as response:
                text = response.read().decode()
        except urllib.error.HTTPError as e:
            text = e.read().decode()
            try:
                message = json.loads(text).get("error", text)
            except ValueError:
                message = text
            raise ServiceError(e.code, message) from None
        return json.loads(text) if text else None

    def status(self) -> dict:
        """The service's version, its rig, the running job and its progress."""
        return self._request("GET", "/api/status")

    def jobs(self) -> list:
        """Every job, newest first."""
        return self._request("GET", "/api/jobs")

    def job(self, job: int) -> dict:
        """One job: its state, request, times, error and summary."""
        return self._request("GET", f"/api/jobs/{int(job)}")

    def acquire(self, out: os.PathLike, **fields: Any) -> int:
        """Queue an acquisition into ``out`` (absolute; made absolute here); ``fields``
        are ``fpm acquire``'s flags without the dashes (``calibrate=True``,
        ``reconstruct=True``, ``step_ms=30``, …). Its job id."""
        body = {"kind": "acquire", "out": str(Path(out).absolute()), **fields}
        return self._request("POST", "/api/jobs", body)["id"]

    def cancel(self, job: int) -> None:
        """Cancel ``job``: a queued one never starts, a running one stops and keeps
        what it captured."""
        self._request("POST", f"/api/jobs/{int(job)}/cancel")

    def wait(self, job: int, timeout: float = 600.0, poll: float = 0.1) -> dict:
        """``job`` once it has ended (``TimeoutError`` if not within ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        while True:
            record = self.job(job)
            if record["state"] in FINAL_STATES:
                return record
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job} is still {record['state']} after {timeout} s")
            time.sleep(poll)

    def events(self) -> Iterator[dict]:
        """The service's events from now on, as they come (``{"event": "state", "job",
        "state", "error"}`` or ``{"event": "progress", "job", "progress"}``): the
        stream is open when this returns, so a job queued next is seen from its start.
        Stop iterating (or close the iterator) to disconnect."""
        request = urllib.request.Request(
            f"http://{self.address}/api/events", headers={"Accept": "text/event-stream"}
        )
        stream = urllib.request.urlopen(request, timeout=self.timeout)

        def read() -> Iterator[dict]:
            with stream:
                for raw in stream:
                    line = raw.decode().rstrip("\r\n")
                    if line.startswith("data:"):
                        yield json.loads(line[5:].strip())

        return read()
