"""A viewer job that writes a file and offers it to the browser that asked (export, video)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable

from splat_core.errors import InputError

log = logging.getLogger(__name__)


def produce_and_send(client, info, produce: Callable[[], Path | None], what: str,
                     notice: Callable[[Path], tuple[str, str]]) -> None:
    """Run `produce` (a path, or None when nothing was made); errors go to the `info` markdown as
    one line, the file to `client` as a download with the notification `notice(path)`."""
    try:
        path = produce()
    except InputError as e:
        info.content = f"⚠ {e}"
        return
    except Exception as e:   # noqa: BLE001 - shown in the panel; the viewer keeps running
        log.exception("%s failed", what)
        info.content = f"⚠ {what} failed: {e}"
        return
    if path is not None and client is not None:
        client.send_file_download(path.name, path.read_bytes(), save_immediately=True)
        title, body = notice(path)
        client.add_notification(title, body, auto_close_seconds=8.0)
