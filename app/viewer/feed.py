"""The viewer's snapshot feed: SLAM's (or a browsed run's) snapshots, merged with a refined map.

    feed = SnapshotFeed(source)          # source: a SlamWorker or a StaticSource (latest())
    feed.publish_refined(arrays)         # the Refine job hands over a map (thread-safe)
    snap = feed.latest()                 # what every part of the viewer draws

The feed is the viewer's one data source. The Refine panel only publishes maps into it; it never
owns or wraps the source. Once a run has finished (or is browsed) and a refined map exists, the
feed's snapshots carry that map. Versions are renumbered here (one counter over both streams), so
the viewer sees a new snapshot whenever either the source's snapshot or the refined map changes;
`map_version` changes only when the map drawn changed.

Run controls (pause, resume, step) are not part of the feed: the viewer calls them on the
source itself (`controls_of`).
"""

from __future__ import annotations

import dataclasses
import threading

from ..snapshot import MapSnapshot

READY_STATES = ("finished", "browse")    # a refined map replaces the run's map only then


class SnapshotFeed:
    def __init__(self, source):
        self.source = source
        self._lock = threading.Lock()
        self._refined: dict | None = None
        self._generation = 0
        self._key = self._map_key = None
        self._snapshot: MapSnapshot | None = None
        self._versions = self._map_versions = 0
        self._listeners: list = []

    # ------------------------------------------------------------------ the refined map
    def publish_refined(self, arrays: dict) -> int:
        """Show `arrays` (read-only Gaussian arrays) as the map once the run is finished; returns
        the generation number of this map."""
        with self._lock:
            self._refined = arrays
            self._generation += 1
            generation = self._generation
        for listener in list(self._listeners):
            listener()
        return generation

    def on_refined(self, listener) -> None:
        """Call `listener()` after each refined map is published (the viewer wakes its loop)."""
        self._listeners.append(listener)

    def refined(self) -> tuple[dict | None, int]:
        """(the newest refined map or None, how many were published)."""
        with self._lock:
            return self._refined, self._generation

    # ------------------------------------------------------------------ snapshots
    def base(self) -> MapSnapshot | None:
        """The source's own newest snapshot (no refined map)."""
        return self.source.latest()

    def latest(self) -> MapSnapshot | None:
        base = self.source.latest()
        if base is None:
            return None
        refined, generation = self.refined()
        use = refined is not None and base.state in READY_STATES
        key = (base.version, generation if use else 0)
        with self._lock:
            if key != self._key:
                map_key = (base.map_version, generation if use else 0)
                if map_key != self._map_key:
                    self._map_key, self._map_versions = map_key, self._map_versions + 1
                self._key, self._versions = key, self._versions + 1
                changes = dict(version=self._versions, map_version=self._map_versions)
                if use:
                    changes["gaussians"] = refined
                self._snapshot = dataclasses.replace(base, **changes)
            return self._snapshot


def controls_of(source):
    """The source when it can be paused (a SlamWorker), else None (browsing)."""
    return source if all(hasattr(source, a) for a in ("pause", "resume", "step_once")) else None
