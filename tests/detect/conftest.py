"""Fixtures of the detector tests."""

import pytest


@pytest.fixture
def worker_pools(monkeypatch) -> list[int]:
    """The sizes of the process pools ``detect_files`` starts from now on in this test (a pool
    that counts itself in place of ``ProcessPoolExecutor``), to check the files went to workers."""
    import cotrain.io.detections as detections

    sizes: list[int] = []

    class CountedPool(detections.ProcessPoolExecutor):
        def __init__(self, max_workers=None, *args, **kwargs):
            sizes.append(max_workers)
            super().__init__(max_workers, *args, **kwargs)

    monkeypatch.setattr(detections, "ProcessPoolExecutor", CountedPool)
    return sizes
