"""deploy/docker-compose.milvus.yml, read: official pinned images for Milvus and its dependencies, every
posedesc replica on the one Milvus and the one shared volume, the load balancer's configuration beside it.
(Its images cannot be pulled on this machine; tests/deploy/test_image.py runs the posedesc image against
the real Milvus of the tests.)"""

from __future__ import annotations

from pathlib import Path

import yaml

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_compose_file_wires_replicas_to_one_milvus_and_one_shared_volume():
    spec = yaml.safe_load((DEPLOY / "docker-compose.milvus.yml").read_text())
    services = spec["services"]
    assert services["milvus"]["image"] == "milvusdb/milvus:v2.3.5"  # the server version the tests run
    for name in ("etcd", "minio", "milvus", "lb"):
        image = services[name]["image"]
        assert ":" in image and not image.endswith(":latest"), image  # pinned
    env = services["milvus"]["environment"]
    assert env["ETCD_ENDPOINTS"] == "etcd:2379" and env["MINIO_ADDRESS"] == "minio:9000"
    replica = services["posedesc"]
    assert replica["environment"]["POSEDESC_STORE"] == "http://milvus:19530"
    assert replica["deploy"]["replicas"] >= 2
    assert "posedesc-shared:/data" in replica["volumes"] and "--data-dir" in replica["command"]
    assert replica["command"][replica["command"].index("--data-dir") + 1] == "/data"
    assert set(spec["volumes"]) >= {"posedesc-shared", "milvus-data", "etcd-data", "minio-data"}
    conf_mount = services["lb"]["volumes"][0].split(":")[0]
    conf = (DEPLOY / conf_mount).read_text()
    assert "proxy_pass http://posedesc;" in conf and "server posedesc:8000;" in conf
