"""The store contract (`tests.store.store_suite.StoreTests`) run by every cache store."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.store.store_suite import LocalStore, S3Store, StoreBackend, StoreTests, TensorstoreStore


class TestLocalStore(StoreTests):
    @pytest.fixture
    def backend(self, tmp_path: Path) -> StoreBackend:
        return LocalStore(tmp_path)


class TestTensorstoreStore(StoreTests):
    @pytest.fixture
    def backend(self, tmp_path: Path) -> StoreBackend:
        pytest.importorskip("tensorstore")
        return TensorstoreStore(tmp_path)


class TestS3Store(StoreTests):
    @pytest.fixture
    def backend(self, tmp_path: Path, s3: str) -> StoreBackend:
        return S3Store(tmp_path, s3)
