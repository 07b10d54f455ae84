"""The keys of a node network: who may join the studio's Zenoh session, and under which name.

A network has its own certificate authority (an EC P-256 key and a self-signed certificate, made by the studio:
:func:`make_authority`). Every member, the studio and each node, holds one *key bundle*: a PEM file of three
blocks, the network's CA certificate, the member's certificate (its common name is the member's name: ``studio``,
``sn1``) and the member's private key (:func:`issue_bundle`). That one file is all a node's computer needs
(``calib-studio node --keys sn1.keys.pem``).

The transport's own security does the rest (Zenoh's TLS with mutual authentication and its access control, no
scheme of ours; see :func:`tls_settings` and :func:`studio_access_control`):

- a peer whose certificate the network's CA did not sign cannot open a link to the studio (TLS refuses it);
- a member may publish, declare and reply only under ``calib/node/<its common name>/**``: a node holding sn3's
  keys cannot speak as sn1, whatever ``--name`` it is given (the studio's access control drops it).

Nodes do not check the studio's host name against its certificate (``verify_name_on_connect`` off): the studio's
address is not known when the keys are made, and any certificate the network's CA signed is a member.
"""

from __future__ import annotations

import base64
import datetime
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from backend.core.errors import InputError

STUDIO = "studio"
"""The studio's common name in its certificate."""
MEMBER_NAME = re.compile(r"[A-Za-z0-9_\-]{1,64}")
"""A member's name (a node's ``--name``): one Zenoh key chunk."""
VALID_DAYS = 3650
"""How long certificates are valid (days): the network lives as long as the rig."""
MAX_BUNDLE_BYTES = 64_000
"""Largest key bundle read (bytes): three PEM blocks are about 2 kB."""
ALL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable", "liveliness_token",
                "liveliness_query", "declare_liveliness_subscriber"]
"""Every message kind Zenoh's access control knows."""


@dataclass(frozen=True)
class Authority:
    """A network's certificate authority: what signs its members' certificates."""

    certificate: x509.Certificate
    key: ec.EllipticCurvePrivateKey

    def certificate_pem(self) -> bytes:
        return self.certificate.public_bytes(serialization.Encoding.PEM)

    def key_pem(self) -> bytes:
        return _key_pem(self.key)


@dataclass(frozen=True)
class KeyBundle:
    """One member's keys, read and checked: its name, the network's CA and its own certificate and key (PEM)."""

    name: str
    """The member's name, the common name of its certificate (``studio``, ``sn1``)."""
    ca_pem: bytes
    certificate_pem: bytes
    key_pem: bytes
    source: str
    """Where it was read from (a file name), for messages."""
    fingerprint: str
    """SHA-256 of the network's CA certificate (hex, first 16 digits): the same on every member of one network."""


CA_CERTIFICATE = "network-ca.pem"
CA_KEY = "network-ca.key"
STUDIO_BUNDLE = "studio.keys.pem"
NODES_FOLDER = "nodes"
BUNDLE_SUFFIX = ".keys.pem"
"""A key folder (:func:`backend.services.network_keys.create_network_keys`) holds the CA's certificate and key
(the key stays on the studio's computer), the studio's bundle and ``nodes/<name>.keys.pem`` per node."""


@dataclass(frozen=True)
class NetworkKeys:
    """What the studio's end of a network needs: its own bundle and the nodes admitted (by name)."""

    folder: Path
    studio: KeyBundle
    nodes: tuple[str, ...]
    """The names of the node bundles issued (each file's certificate, checked)."""
    problems: tuple[str, ...] = ()
    """Node bundles that could not be read, each named with why (those nodes are not admitted)."""

    def bundle_path(self, node: str) -> Path:
        """The file to copy to ``node``'s computer (its ``--keys``)."""
        return self.folder / NODES_FOLDER / f"{node}{BUNDLE_SUFFIX}"

    def agent_command(self, node: str) -> str:
        """The command ``node``'s computer runs, its bundle copied beside it (the studio's host and the device
        left for the user to fill in)."""
        return (f"calib-studio node --name {node} --keys {self.bundle_path(node).name} --connect tls/STUDIO_HOST:7447 "
                f"--device ...")


def load_network_keys(folder: Path) -> NetworkKeys:
    """The key folder's studio bundle and its admitted nodes; :class:`InputError` naming the folder when it holds
    no network's keys, or the studio bundle when it is broken. A broken node bundle is listed in ``problems``
    (that node is not admitted) and hides no other."""
    folder = Path(folder)
    if not (folder / STUDIO_BUNDLE).is_file():
        raise InputError(f"{folder.name}: no {STUDIO_BUNDLE} in it; expected a folder of network keys the studio "
                         f"made (calib-studio node-keys)", "keys")
    studio = read_bundle(folder / STUDIO_BUNDLE)
    nodes, problems = [], []
    for path in sorted((folder / NODES_FOLDER).glob(f"*{BUNDLE_SUFFIX}")):
        try:
            bundle = read_bundle(path)
        except InputError as exc:
            problems.append(exc.message)
            continue
        if bundle.fingerprint != studio.fingerprint:
            problems.append(f"{path.name}: its keys belong to another network (CA {bundle.fingerprint}, the "
                            f"studio's is {studio.fingerprint})")
        elif bundle.name != path.name.removesuffix(BUNDLE_SUFFIX):
            problems.append(f"{path.name}: its certificate names {bundle.name}")
        else:
            nodes.append(bundle.name)
    return NetworkKeys(folder, studio, tuple(nodes), tuple(problems))


def make_authority(now: datetime.datetime | None = None) -> Authority:
    """A new network's certificate authority (self-signed, valid :data:`VALID_DAYS`)."""
    now = now or datetime.datetime.now(datetime.UTC)
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "calib-studio node network")])
    usage = x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
                          key_encipherment=False, data_encipherment=False, key_agreement=False, encipher_only=False,
                          decipher_only=False)
    certificate = (_builder(name, key, now).issuer_name(name)
                   .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
                   .add_extension(usage, critical=True)
                   .sign(key, hashes.SHA256()))
    return Authority(certificate, key)


def issue_bundle(authority: Authority, name: str, now: datetime.datetime | None = None) -> bytes:
    """The key bundle (PEM bytes: CA certificate, certificate, private key) of member ``name``."""
    check_member_name(name)
    now = now or datetime.datetime.now(datetime.UTC)
    key = ec.generate_private_key(ec.SECP256R1())
    certificate = (_builder(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]), key, now)
                   .issuer_name(authority.certificate.subject)
                   .add_extension(x509.SubjectAlternativeName([x509.DNSName(name)]), critical=False)
                   .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                   .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                         ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                   .sign(authority.key, hashes.SHA256()))
    return (authority.certificate_pem() + certificate.public_bytes(serialization.Encoding.PEM) + _key_pem(key))


def read_authority(certificate_file: Path, key_file: Path) -> Authority:
    """The CA a key folder holds (to issue more members); :class:`InputError` naming the file that is unreadable,
    not PEM, or whose key does not belong to the certificate."""
    certificate = _certificates(_read(certificate_file), certificate_file.name)
    try:
        key = serialization.load_pem_private_key(_read(key_file), password=None)
    except (ValueError, TypeError):
        raise InputError(f"{key_file.name}: expected the network CA's private key (PEM, unencrypted)",
                         "keys") from None
    if len(certificate) != 1 or not _public_equal(certificate[0].public_key(), key.public_key()):
        raise InputError(f"{key_file.name} is not the key of {certificate_file.name}'s certificate", "keys")
    return Authority(certificate[0], key)


def read_bundle(path: Path) -> KeyBundle:
    """A member's key bundle, checked; :class:`InputError` naming the file and what is wrong: unreadable, not
    the three PEM blocks, a certificate the bundle's CA did not sign, a key of another certificate, expired."""
    return parse_bundle(_read(path), path.name)


def parse_bundle(data: bytes, source: str) -> KeyBundle:
    """:func:`read_bundle` of bytes read elsewhere (``source`` names them in messages; the input is ``keys``)."""
    expected = "expected a key bundle: the network CA's certificate, the member's certificate and its private key"
    certificates = _certificates(data, source)
    if len(certificates) != 2:
        raise InputError(f"{source}: {len(certificates)} certificate(s); {expected}", "keys")
    ca, certificate = certificates
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError):
        raise InputError(f"{source}: no readable private key; {expected}", "keys") from None
    try:
        certificate.verify_directly_issued_by(ca)
    except (ValueError, TypeError, InvalidSignature):
        raise InputError(f"{source}: its certificate was not signed by the network CA it carries", "keys") from None
    if not _public_equal(certificate.public_key(), key.public_key()):
        raise InputError(f"{source}: its private key does not belong to its certificate", "keys")
    now = datetime.datetime.now(datetime.UTC)
    if not certificate.not_valid_before_utc <= now <= certificate.not_valid_after_utc:
        raise InputError(f"{source}: its certificate is valid from {certificate.not_valid_before_utc:%Y-%m-%d} to "
                         f"{certificate.not_valid_after_utc:%Y-%m-%d} only; issue new keys", "keys")
    names = certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    name = str(names[0].value) if names else ""
    if not MEMBER_NAME.fullmatch(name):
        raise InputError(f"{source}: its certificate names {name!r}, not a member of a node network", "keys")
    ca_pem = ca.public_bytes(serialization.Encoding.PEM)
    return KeyBundle(name, ca_pem, certificate.public_bytes(serialization.Encoding.PEM), _key_pem(key), source,
                     ca.fingerprint(hashes.SHA256()).hex()[:16])


def check_member_name(name: str) -> str:
    """``name`` if it can name a member (1-64 letters, digits, ``_``, ``-``), else :class:`InputError`."""
    if not isinstance(name, str) or not MEMBER_NAME.fullmatch(name):
        raise InputError(f"node name {name!r}: expected 1-64 letters, digits, '_' or '-'", "name")
    return name


def tls_settings(bundle: KeyBundle) -> dict[str, Any]:
    """Zenoh's ``transport.link.tls`` settings for a member: its certificate on both ends of every link, the
    network's CA as the only root, client certificates required (mutual TLS), host names not checked."""
    own_key, own_certificate = _base64(bundle.key_pem), _base64(bundle.certificate_pem)
    return {"root_ca_certificate_base64": _base64(bundle.ca_pem), "enable_mtls": True,
            "listen_private_key_base64": own_key, "listen_certificate_base64": own_certificate,
            "connect_private_key_base64": own_key, "connect_certificate_base64": own_certificate,
            "verify_name_on_connect": False}


def studio_access_control(nodes: list[str]) -> dict[str, Any]:
    """Zenoh's ``access_control`` for the studio: everything it sends is allowed; what it receives only under
    ``calib/node/<name>/**`` from the member whose certificate names ``<name>`` (and a simulated node's answers
    on ``calib/sim/**``); the rest, and every peer without a certificate of ``nodes``, is denied."""
    rules: list[dict[str, Any]] = [
        {"id": "studio-sends", "messages": ALL_MESSAGES, "flows": ["egress"], "permission": "allow",
         "key_exprs": ["**"]},
        {"id": "simulation", "messages": ["declare_queryable", "reply"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": ["calib/sim/**"]}]
    subjects: list[dict[str, Any]] = [{"id": "anyone"}]
    policies: list[dict[str, Any]] = [{"rules": ["studio-sends"], "subjects": ["anyone"]}]
    members = [check_member_name(node) for node in dict.fromkeys(nodes)]
    if members:
        subjects.append({"id": "members", "cert_common_names": members})
        policies.append({"rules": ["simulation"], "subjects": ["members"]})
    for node in members:
        rules.append({"id": f"from-{node}", "messages": ALL_MESSAGES, "flows": ["ingress"], "permission": "allow",
                      "key_exprs": [f"calib/node/{node}/**"]})
        subjects.append({"id": f"node-{node}", "cert_common_names": [node]})
        policies.append({"rules": [f"from-{node}"], "subjects": [f"node-{node}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def _builder(subject: x509.Name, key: ec.EllipticCurvePrivateKey, now: datetime.datetime) -> x509.CertificateBuilder:
    return (x509.CertificateBuilder().subject_name(subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))  # a node's clock a little behind still accepts
            .not_valid_after(now + datetime.timedelta(days=VALID_DAYS)))


def _certificates(data: bytes, source: str) -> list[x509.Certificate]:
    try:
        return x509.load_pem_x509_certificates(data)
    except ValueError:
        raise InputError(f"{source}: no PEM certificate in it; expected the keys the studio made for the network",
                         "keys") from None


def _read(path: Path) -> bytes:
    """The file's bytes, at most :data:`MAX_BUNDLE_BYTES`; :class:`InputError` naming it when it cannot be read."""
    try:
        with Path(path).open("rb") as handle:
            data = handle.read(MAX_BUNDLE_BYTES + 1)
    except OSError as exc:
        raise InputError(f"{Path(path).name}: cannot read the key file ({exc.strerror or exc})", "keys") from None
    if len(data) > MAX_BUNDLE_BYTES:
        raise InputError(f"{Path(path).name}: more than {MAX_BUNDLE_BYTES:,} bytes; expected a key bundle of a few "
                         f"kB", "keys")
    return data


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _public_equal(a: Any, b: Any) -> bool:
    encoding, form = serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    return a.public_bytes(encoding, form) == b.public_bytes(encoding, form)


def _base64(pem: bytes) -> str:
    return base64.b64encode(pem).decode("ascii")
