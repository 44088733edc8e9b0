"""The scene follows the verdict on its own thread and only the newest waiting answer's scene is built."""

from __future__ import annotations

import threading
import time

from refine.serve.app import Hub, SceneBuilder


class Slow:
    """Stands in for the scene sections: the first build waits until released."""

    def __init__(self) -> None:
        self.release, self.started, self.built = threading.Event(), threading.Event(), []

    def messages(self, answer):
        self.started.set()
        self.release.wait(5)
        self.built.append(answer)
        return f"changed {answer}", f"whole {answer}"


def test_submit_returns_at_once_and_an_overtaken_scene_is_never_built():
    hub = Hub()
    builder = SceneBuilder(hub)
    builder.scenes = slow = Slow()
    try:
        builder.submit(1)
        assert slow.started.wait(5)
        t0 = time.process_time()
        builder.submit(2)  # waits behind 1 ...
        builder.submit(3)  # ... and is overtaken by 3
        assert time.process_time() - t0 < 1.0  # the solver's thread is not held by the scene
        slow.release.set()
        for _ in range(500):
            if slow.built == [1, 3] and hub.last.get("scene") == "whole 3":
                break
            time.sleep(0.01)
        assert slow.built == [1, 3]
        assert builder.skipped == 1 and builder.built == 2
        assert hub.last["scene"] == "whole 3"
    finally:
        slow.release.set()
        builder.stop()
