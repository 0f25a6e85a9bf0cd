"""GUI built on the pages of the visitors who may control the run, and on no other page.

    gui = ControlGui()                       # panels lay out widgets on it as on server.gui
    with gui.add_folder("Run controls"):
        pause = gui.add_button("Pause")
    pause.on_click(lambda event: ...)
    gui.attach(client)                       # on_client_connect, for a "control" visitor
    pause.disabled = True                    # sets it on every attached page

viser's shared GUI (`server.gui`) reaches every page, so a view-only visitor would see (and could
press) pause, export and refine. Here every widget is a `SharedWidget`: a record of how to build it
plus its current state. `attach(client)` builds the whole layout on that client's own GUI
(`client.gui`: only that page, and only that connection can send its events) and starts it from
the current state; setting `value`, `content`, `disabled`, ... sets it on every attached page and
is remembered for pages that come later. An input changed on one page is copied to the others and
then calls the widget's callbacks once, with the event of the page that changed it (`event.client`).
Setting `value` from Python calls them too, with a client-less event, as viser's own widgets do.

An input made with `per_page=True` is each page's own choice (the export format): a change on one
page stays on that page, `value_for(client_id)` reads it, and a new page starts from `value`.
Setting `value` from Python sets it on every page again.
"""

from __future__ import annotations

import contextlib
import threading
from types import SimpleNamespace

STATE_NAMES = ("value", "content", "disabled", "visible", "max", "min", "image", "label", "hint", "options")


class SharedWidget:
    def __init__(self, gui: "ControlGui", kind: str, args: tuple, kwargs: dict, per_page: bool = False):
        state = {}
        if "initial_value" in kwargs:
            state["value"] = kwargs["initial_value"]
        elif kind == "add_progress_bar":
            state["value"] = args[0] if args else kwargs.get("value", 0.0)
        if kind == "add_markdown":
            state["content"] = args[0] if args else kwargs.get("content", "")
        for name in ("disabled", "visible", "max", "min"):
            if name in kwargs:
                state[name] = kwargs[name]
        if kind in ("add_button", "add_checkbox", "add_number", "add_dropdown", "add_slider", "add_text"):
            state.setdefault("disabled", False)
        state.setdefault("visible", True)
        object.__setattr__(self, "_gui", gui)
        object.__setattr__(self, "_kind", kind)
        object.__setattr__(self, "_args", args)
        object.__setattr__(self, "_kwargs", kwargs)
        object.__setattr__(self, "_state", state)
        object.__setattr__(self, "_handles", {})       # client id -> viser handle
        object.__setattr__(self, "_per_page", per_page)
        object.__setattr__(self, "_page_values", {})   # client id -> that page's own value (per_page)
        object.__setattr__(self, "callbacks", [])

    # ------------------------------------------------------------------ state
    def __getattr__(self, name):
        state = object.__getattribute__(self, "_state")
        if name in state:
            return state[name]
        raise AttributeError(name)

    def __setattr__(self, name, value):
        if name not in STATE_NAMES:
            raise AttributeError(f"{name}: a shared widget holds only {STATE_NAMES}")
        with self._gui.lock:
            self._state[name] = value
            if name == "value":
                self._page_values.clear()
            handles = list(self._handles.values())
        for handle in handles:
            _set(handle, name, value)
        if name == "value" and self._kind != "add_markdown":
            self._fire(SimpleNamespace(client=None, client_id=None, target=self))

    def value_for(self, client_id: int | None):
        """The value on that page (a per-page input's own choice), else the shared value."""
        with self._gui.lock:
            return self._page_values.get(client_id, self._state.get("value"))

    def on_click(self, callback):
        self.callbacks.append(callback)
        return callback

    on_update = on_click

    def _fire(self, event) -> None:
        for callback in list(self.callbacks):
            callback(event)

    # ------------------------------------------------------------------ pages
    def _build(self, client) -> None:
        kwargs = dict(self._kwargs)
        with self._gui.lock:
            state = dict(self._state)
        kwargs["visible"] = state["visible"]
        if "disabled" in state:
            kwargs["disabled"] = state["disabled"]
        for name in ("max", "min"):
            if name in kwargs:
                kwargs[name] = state[name]
        args = self._args
        if "value" in state:
            if "initial_value" in kwargs:
                kwargs["initial_value"] = state["value"]
            elif self._kind == "add_progress_bar":
                args, kwargs["value"] = (), state["value"]
        if "content" in state:
            args, kwargs["content"] = (), state["content"]
        handle = getattr(client.gui, self._kind)(*args, **kwargs)
        cid = client.client_id
        if self._kind == "add_button":
            handle.on_click(lambda event: self._from_page(event, cid))
        elif hasattr(handle, "on_update"):
            handle.on_update(lambda event: self._from_page(event, cid))
        with self._gui.lock:
            self._handles[cid] = handle

    def _from_page(self, event, cid: int) -> None:
        if getattr(event, "client", None) is None:   # our own fan-out, not the visitor
            return
        if self._kind != "add_button":
            handle = self._handles.get(cid)
            if handle is None:
                return
            value = handle.value
            with self._gui.lock:
                if self._per_page:
                    self._page_values[cid] = value
                    others = []
                else:
                    self._state["value"] = value
                    others = [h for c, h in self._handles.items() if c != cid]
            for other in others:
                _set(other, "value", value)
        self._fire(event)


def _set(handle, name: str, value) -> None:
    try:
        if getattr(handle, name) != value if name != "image" else True:
            setattr(handle, name, value)
    except Exception:   # noqa: BLE001 - a page that just left
        pass


class ControlGui:
    """Records a layout (folders and widgets) and builds it on each controlling client's page."""

    def __init__(self):
        self.lock = threading.RLock()
        self._layout: list = []           # ("folder", args, kwargs, children) or SharedWidget
        self._stack = [self._layout]
        self._clients: set[int] = set()

    @contextlib.contextmanager
    def add_folder(self, *args, **kwargs):
        children: list = []
        self._stack[-1].append(("folder", args, kwargs, children))
        self._stack.append(children)
        try:
            yield self
        finally:
            self._stack.pop()

    def _widget(self, kind: str, *args, per_page: bool = False, **kwargs) -> SharedWidget:
        widget = SharedWidget(self, kind, args, kwargs, per_page)
        self._stack[-1].append(widget)
        return widget

    def __getattr__(self, kind: str):
        if kind.startswith("add_"):
            return lambda *args, **kwargs: self._widget(kind, *args, **kwargs)
        raise AttributeError(kind)

    # ------------------------------------------------------------------ pages
    def attach(self, client) -> None:
        with self.lock:
            self._clients.add(client.client_id)
        self._build(client, self._layout)

    def _build(self, client, items: list) -> None:
        for item in items:
            if isinstance(item, SharedWidget):
                item._build(client)
            else:
                _, args, kwargs, children = item
                with client.gui.add_folder(*args, **kwargs):
                    self._build(client, children)

    def detach(self, client_id: int) -> None:
        with self.lock:
            self._clients.discard(client_id)
            self._forget(client_id, self._layout)

    def _forget(self, client_id: int, items: list) -> None:
        for item in items:
            if isinstance(item, SharedWidget):
                item._handles.pop(client_id, None)
                item._page_values.pop(client_id, None)
            else:
                self._forget(client_id, item[3])

    @property
    def clients(self) -> set[int]:
        with self.lock:
            return set(self._clients)
