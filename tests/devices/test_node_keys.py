"""A node network's keys: made by ``calib-studio node-keys``, read back checked, and every bad key file named.

(That a peer without them cannot join, and that one node's keys cannot speak as another, is tested with real
agent processes in ``test_node_network.py``.)
"""

from __future__ import annotations

import datetime
import json
import re
import stat

import pytest

from backend.core.errors import InputError
from backend.devices.node_keys import (
    issue_bundle,
    load_network_keys,
    make_authority,
    parse_bundle,
    read_bundle,
    studio_access_control,
)
from backend.services.network_keys import add_node_keys, create_network_keys, ensure_network_keys
from studio.cli import main as cli_main


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    return create_network_keys(tmp_path_factory.mktemp("net") / "keys", ["sn1", "sn2"])


def test_a_network_is_made_with_one_bundle_per_node_readable_by_its_owner_only(keys) -> None:
    assert keys.nodes == ("sn1", "sn2") and keys.problems == () and keys.studio.name == "studio"
    files = sorted(p.relative_to(keys.folder).as_posix() for p in keys.folder.rglob("*") if p.is_file())
    assert files == ["network-ca.key", "network-ca.pem", "nodes/sn1.keys.pem", "nodes/sn2.keys.pem",
                     "studio.keys.pem"]
    for path in keys.folder.rglob("*.pem"):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path
    assert stat.S_IMODE(keys.folder.stat().st_mode) == 0o700
    sn1 = read_bundle(keys.bundle_path("sn1"))
    assert sn1.name == "sn1" and sn1.fingerprint == keys.studio.fingerprint  # one network


def test_nodes_are_added_to_a_network_and_never_issued_twice(tmp_path) -> None:
    folder = tmp_path / "keys"
    first = ensure_network_keys(folder, ["sn1"])
    grown = ensure_network_keys(folder, ["sn1", "sn3"])
    assert grown.nodes == ("sn1", "sn3") and grown.studio.fingerprint == first.studio.fingerprint
    with pytest.raises(InputError, match="^nodes sn3 already have keys"):
        add_node_keys(folder, ["sn3"])
    with pytest.raises(InputError, match="keys already exists and is not empty"):
        create_network_keys(folder, ["sn9"])
    for names, message in ((["studio"], "'studio' is the studio's own name"), (["a/b"], "node name 'a/b'"),
                           ([], "no node names"), (["x", "x"], "nodes x already have keys")):
        with pytest.raises(InputError, match=message):
            create_network_keys(tmp_path / "fresh", names)
    assert not (tmp_path / "fresh").exists()  # nothing half-made


def test_a_broken_node_bundle_is_named_and_hides_no_other(tmp_path) -> None:
    keys = create_network_keys(tmp_path / "keys", ["sn1", "sn2", "sn3"])
    keys.bundle_path("sn1").write_text("not a key")
    other = create_network_keys(tmp_path / "other", ["sn2"])
    keys.bundle_path("sn2").write_bytes(other.bundle_path("sn2").read_bytes())
    loaded = load_network_keys(keys.folder)
    assert loaded.nodes == ("sn3",)
    assert loaded.problems[0] == ("sn1.keys.pem: no PEM certificate in it; expected the keys the studio made for "
                                  "the network")
    assert loaded.problems[1].startswith("sn2.keys.pem: its keys belong to another network")


def test_bad_bundles_are_refused_naming_the_file_and_what_is_wrong(keys, tmp_path) -> None:
    good = keys.bundle_path("sn1").read_bytes()
    blocks = good.split(b"-----END CERTIFICATE-----\n")
    ca_block, cert_block, key_block = blocks[0] + b"-----END CERTIFICATE-----\n", \
        blocks[1] + b"-----END CERTIFICATE-----\n", blocks[2]
    foreign = issue_bundle(make_authority(), "sn1")
    foreign_key = foreign[foreign.index(b"-----BEGIN PRIVATE KEY-----"):]
    old = make_authority(datetime.datetime(2000, 1, 1, tzinfo=datetime.UTC))
    expired = issue_bundle(old, "sn1", datetime.datetime(2000, 1, 1, tzinfo=datetime.UTC))
    cases = {
        b"hello": "no PEM certificate in it",
        cert_block + key_block: "1 certificate(s); expected a key bundle",
        ca_block + cert_block: "no readable private key",
        ca_block + cert_block + foreign_key: "its private key does not belong to its certificate",
        foreign[:foreign.index(b"-----END CERTIFICATE-----") + 26] + cert_block + key_block:
            "its certificate was not signed by the network CA it carries",
        expired: "its certificate is valid from 1999-12-31 to 2009-12-29 only; issue new keys",
    }
    for data, message in cases.items():
        with pytest.raises(InputError, match=re.escape(message)) as error:
            parse_bundle(data, "sn1.keys.pem")
        assert error.value.message.startswith("sn1.keys.pem: ") and error.value.input == "keys"
    with pytest.raises(InputError, match=r"^missing.pem: cannot read the key file \(No such file or directory\)$"):
        read_bundle(tmp_path / "missing.pem")
    (tmp_path / "huge.pem").write_bytes(b"x" * 70_000)
    with pytest.raises(InputError, match="huge.pem: more than 64,000 bytes"):
        read_bundle(tmp_path / "huge.pem")


def test_the_studio_admits_each_node_only_under_its_own_name() -> None:
    acl = studio_access_control(["sn1", "sn2"])
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {rule["id"]: rule for rule in acl["rules"]}
    assert rules["from-sn1"]["key_exprs"] == ["calib/node/sn1/**"] and rules["from-sn1"]["flows"] == ["ingress"]
    subjects = {subject["id"]: subject for subject in acl["subjects"]}
    assert subjects["node-sn1"]["cert_common_names"] == ["sn1"]
    assert {"rules": ["from-sn2"], "subjects": ["node-sn2"]} in acl["policies"]


def test_the_cli_makes_keys_and_the_node_refuses_bad_ones_in_one_line(tmp_path, capsys) -> None:
    assert cli_main(["node-keys", str(tmp_path / "net"), "--nodes", "sn1, sn2", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert sorted(summary["nodes"]) == ["sn1", "sn2"] and summary["problems"] == []
    assert cli_main(["node-keys", str(tmp_path / "net"), "--nodes", "sn1"]) == 2
    assert capsys.readouterr().err.strip() == ("error: keys: net already exists and is not empty: network keys go "
                                               "into a new folder (add nodes to an existing network with --add)")
    sn1 = str(tmp_path / "net" / "nodes" / "sn1.keys.pem")
    for args, line in (
            (["--keys", str(tmp_path / "nope.pem"), "--connect", "tls/127.0.0.1:7447"],
             "error: keys: nope.pem: cannot read the key file (No such file or directory)"),
            (["--keys", sn1, "--connect", "tcp/127.0.0.1:7447"],
             "error: connect: endpoint 'tcp/127.0.0.1:7447': with the network's keys every link is TLS; expected "
             "tls/HOST:PORT"),
            (["--connect", "tls/127.0.0.1:7447"],
             "error: connect: endpoint 'tls/127.0.0.1:7447' needs the network's keys (--keys FILE or "
             "CALIB_NODE_KEYS)")):
        assert cli_main(["node", "--name", "sn1", "--device", "sim-cell:sn1", *args]) == 2
        assert capsys.readouterr().err.strip() == line
