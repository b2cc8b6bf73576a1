"""The Milvus store's collections: the objects' records and each model's templates created (by whichever replica
comes first, the others waiting until they are indexed and loaded) and read."""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from index.store.milvus_snapshot import (
    MAX_ROWS,
)


class MilvusCollections:
    """The collections part of `MilvusStore` (its attributes declared here, set there)."""

    _index: Any
    client: Any
    collections: Any
    dims: Any
    objects_collection: Any
    timeout: Any

    def _create_collections(self) -> None:
        from pymilvus import DataType, MilvusClient

        have = set(self.client.list_collections(timeout=self.timeout))
        todo: list[tuple[str, Any, Any]] = []
        # collections made earlier: loaded (a no-op when they are, as after a Milvus restart they become)
        for c in [self.objects_collection, *self.collections.values()]:
            if c in have:
                self._load(c)
        if self.objects_collection not in have:
            s = MilvusClient.create_schema(auto_id=False)
            s.add_field("token", DataType.VARCHAR, is_primary=True, max_length=64)
            s.add_field("object_id", DataType.INT64)
            s.add_field("name", DataType.VARCHAR, max_length=1024)
            s.add_field("state", DataType.INT64)
            s.add_field("symmetry", DataType.VARCHAR, max_length=16)
            s.add_field("faces", DataType.INT64)
            s.add_field("created", DataType.DOUBLE)
            s.add_field("updated", DataType.DOUBLE)
            s.add_field("templates", DataType.VARCHAR, max_length=8192)
            s.add_field("extra", DataType.VARCHAR, max_length=65535)
            s.add_field("v", DataType.FLOAT_VECTOR, dim=2)  # Milvus 2.3: every collection has a vector
            ip = self.client.prepare_index_params()
            ip.add_index("v", index_type="FLAT", metric_type="L2")
            todo.append((self.objects_collection, s, ip))
        for m, coll in self.collections.items():
            if coll in have:
                continue
            s = MilvusClient.create_schema(auto_id=True)
            s.add_field("id", DataType.INT64, is_primary=True)
            s.add_field("object_id", DataType.INT64)
            s.add_field("azimuth", DataType.FLOAT)
            s.add_field("elevation", DataType.FLOAT)
            s.add_field("inplane", DataType.FLOAT)
            s.add_field("descriptor", DataType.FLOAT_VECTOR, dim=self.dims[m])
            ip = self.client.prepare_index_params()
            ip.add_index("descriptor", index_type="HNSW", metric_type="L2", params=self._index)
            todo.append((coll, s, ip))
        # each takes ~3 s (made, indexed, loaded): side by side
        with ThreadPoolExecutor(max(1, len(todo))) as pool:
            list(pool.map(lambda args: self._create(*args), todo))

    def _create(self, name: str, schema: Any, index_params: Any) -> None:
        """Creates a collection; another replica creating it at the same moment is fine."""
        try:
            self.client.create_collection(
                name,
                schema=schema,
                index_params=index_params,
                consistency_level="Bounded",
                timeout=self.timeout,
            )
        except Exception:
            if not self.client.has_collection(name, timeout=self.timeout):
                raise
            # made by another replica, maybe still without its index or not loaded yet: wait for both
            self._load(name)

    def _load(self, name: str) -> None:
        for _ in range(100):
            try:
                self.client.load_collection(name, timeout=30)
                return
            except Exception as e:  # "index not found" while the creator is still indexing it
                last = e
                time.sleep(0.2)
        raise last

    def _query(
        self, expr: str, fields: Sequence[str], limit: int = MAX_ROWS, consistency: str = "Strong"
    ) -> list[dict[str, Any]]:
        return list(
            self.client.query(
                self.objects_collection,
                filter=expr,
                output_fields=list(fields),
                limit=limit,
                consistency_level=consistency,
                timeout=self.timeout,
            )
        )
