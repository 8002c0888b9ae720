"""A local stand-in for the Hugging Face Hub's HTTP API: just enough of it for ``huggingface_hub`` to create a
dataset repo, commit files (the "regular" upload mode: contents inline in the commit), list and move tags, and
for ``snapshot_download`` / ``hf_hub_download`` (what ``LeRobotDataset(repo_id)`` uses) to read a revision back.

Point the client at it with ``HF_ENDPOINT=http://127.0.0.1:<port>`` (read when huggingface_hub is imported, so
in a fresh process). Every commit is a full snapshot; branches and tags name snapshots, as in git. No network.
"""

from __future__ import annotations

import base64
import hashlib
import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import unquote, urlsplit


class HubState:
    def __init__(self):
        self.lock = threading.Lock()
        self.repos: dict[str, dict] = {}   # repo id -> {"commits": {sha: {path: bytes}}, "branches", "tags"}
        self.requests: list[str] = []      # "METHOD path", for the test to look at

    def create(self, repo_id: str) -> None:
        if repo_id not in self.repos:
            sha = _sha({"repo": repo_id})
            self.repos[repo_id] = {"commits": {sha: {}}, "branches": {"main": sha}, "tags": {}}

    def resolve(self, repo: dict, rev: str) -> str | None:
        if rev in repo["branches"]:
            return repo["branches"][rev]
        if rev in repo["tags"]:
            return repo["tags"][rev]
        return rev if rev in repo["commits"] else None


def _sha(obj) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def _blob_oid(content: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(content) + content).hexdigest()


def make_handler(state: HubState):
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):  # quiet
            pass

        # ------------------------------------------------------------ plumbing
        def _body(self) -> bytes:
            length = int(self.headers.get("Content-Length") or 0)
            return self.rfile.read(length) if length else b""

        def _send(self, status: int, payload=None, headers: dict | None = None, body: bytes | None = None,
                  head: bool = False) -> None:
            data = body if body is not None else json.dumps(payload if payload is not None else {}).encode()
            self.send_response(status)
            self.send_header("Content-Type", "application/json" if body is None else "application/octet-stream")
            self.send_header("Content-Length", str(len(data)))
            for k, v in (headers or {}).items():
                self.send_header(k, v)
            self.end_headers()
            if not head:
                self.wfile.write(data)

        def _not_found(self, what: str, head: bool = False) -> None:
            self._send(404, {"error": f"{what} not found"}, headers={"X-Error-Code": "RepoNotFound"}, head=head)

        def _route(self, method: str) -> None:
            path = urlsplit(self.path).path
            state.requests.append(f"{method} {path}")
            parts = [unquote(p) for p in path.split("/")][1:]
            with state.lock:
                if parts[:1] == ["api"]:
                    return self._api(method, parts[1:])
                if len(parts) >= 6 and parts[0] == "datasets" and parts[3] == "resolve":
                    return self._resolve(method, f"{parts[1]}/{parts[2]}", parts[4], "/".join(parts[5:]))
            self._send(404, {"error": f"no route {method} {path}"})

        def do_GET(self):
            self._route("GET")

        def do_HEAD(self):
            self._route("HEAD")

        def do_POST(self):
            self._route("POST")

        def do_DELETE(self):
            self._route("DELETE")

        # ------------------------------------------------------------ the API
        def _api(self, method: str, parts: list[str]) -> None:
            if parts == ["repos", "create"] and method == "POST":
                req = json.loads(self._body())
                repo_id = f"{req['organization']}/{req['name']}" if req.get("organization") else req["name"]
                state.create(repo_id)
                host = self.headers.get("Host")
                return self._send(200, {"url": f"http://{host}/datasets/{repo_id}", "name": repo_id})
            if parts == ["validate-yaml"]:
                self._body()
                return self._send(200, {})
            if len(parts) < 3 or parts[0] != "datasets":
                return self._send(404, {"error": f"unsupported API call {parts}"})
            repo_id, rest = f"{parts[1]}/{parts[2]}", parts[3:]
            repo = state.repos.get(repo_id)
            if repo is None:
                self._body()
                return self._not_found(f"dataset {repo_id}", head=method == "HEAD")
            action = rest[0] if rest else "revision"
            rev = "/".join(rest[1:]) if len(rest) > 1 else "main"
            if action == "preupload" and method == "POST":
                files = json.loads(self._body())["files"]
                return self._send(200, {"files": [{"path": f["path"], "uploadMode": "regular", "shouldIgnore": False}
                                                  for f in files]})
            if action == "commit" and method == "POST":
                return self._commit(repo_id, repo, rev)
            if action == "refs" and method == "GET":
                ref = lambda name, kind, sha: {"name": name, "ref": f"refs/{kind}/{name}", "targetCommit": sha}  # noqa: E731
                return self._send(200, {"branches": [ref(n, "heads", s) for n, s in repo["branches"].items()],
                                        "converts": [], "tags": [ref(n, "tags", s) for n, s in repo["tags"].items()]})
            if action == "tag" and method == "POST":
                req = json.loads(self._body())
                sha = state.resolve(repo, rev)
                if sha is None:
                    return self._not_found(f"revision {rev}")
                if req["tag"] in repo["tags"]:
                    return self._send(409, {"error": f"tag {req['tag']} already exists"})
                repo["tags"][req["tag"]] = sha
                return self._send(200, {})
            if action == "tag" and method == "DELETE":
                if repo["tags"].pop(rev, None) is None:
                    return self._not_found(f"tag {rev}")
                return self._send(200, {})
            if action in ("revision", "tree") and method == "GET":
                revision = rest[1] if len(rest) > 1 else "main"
                sha = state.resolve(repo, revision)
                if sha is None:
                    return self._send(404, {"error": f"revision {revision} not found"},
                                      headers={"X-Error-Code": "RevisionNotFound"})
                files = repo["commits"][sha]
                if action == "tree":
                    prefix = "/".join(rest[2:])
                    return self._send(200, [{"type": "file", "path": p, "size": len(c), "oid": _blob_oid(c)}
                                            for p, c in sorted(files.items()) if p.startswith(prefix)])
                return self._send(200, {"id": repo_id, "sha": sha, "private": False, "disabled": False,
                                        "gated": False, "downloads": 0, "likes": 0, "tags": [],
                                        "lastModified": "2026-01-01T00:00:00.000Z",
                                        "siblings": [{"rfilename": p, "size": len(c)} for p, c in sorted(files.items())]})
            self._body()
            return self._send(404, {"error": f"unsupported {method} {action}"})

        def _commit(self, repo_id: str, repo: dict, branch: str) -> None:
            lines = [json.loads(line) for line in self._body().splitlines() if line.strip()]
            parent = repo["branches"].get(branch)
            if parent is None:
                return self._not_found(f"branch {branch}")
            files = dict(repo["commits"][parent])
            for line in lines:
                key, value = line["key"], line["value"]
                if key == "file":
                    files[value["path"]] = base64.b64decode(value["content"])
                elif key == "deletedFile":
                    files.pop(value["path"], None)
                elif key == "deletedFolder":
                    prefix = value["path"].rstrip("/") + "/"
                    files = {p: c for p, c in files.items() if not p.startswith(prefix)}
                elif key != "header":
                    return self._send(400, {"error": f"the stand-in does not support commit entries {key!r}"})
            sha = _sha({"parent": parent, "files": {p: _blob_oid(c) for p, c in files.items()}})
            repo["commits"][sha] = files
            repo["branches"][branch] = sha
            host = self.headers.get("Host")
            self._send(200, {"commitUrl": f"http://{host}/datasets/{repo_id}/commit/{sha}", "commitOid": sha,
                             "success": True})

        def _resolve(self, method: str, repo_id: str, rev: str, path: str) -> None:
            head = method == "HEAD"
            repo = state.repos.get(repo_id)
            if repo is None:
                return self._not_found(f"dataset {repo_id}", head=head)
            sha = state.resolve(repo, rev)
            if sha is None:
                return self._send(404, {"error": f"revision {rev}"}, headers={"X-Error-Code": "RevisionNotFound"},
                                  head=head)
            content = repo["commits"][sha].get(path)
            if content is None:
                return self._send(404, {"error": f"{path}"}, headers={"X-Error-Code": "EntryNotFound",
                                                                     "X-Repo-Commit": sha}, head=head)
            self._send(200, body=content, head=head,
                       headers={"X-Repo-Commit": sha, "ETag": f'"{_blob_oid(content)}"'})

    return Handler


class HubStandIn:
    """``with HubStandIn() as hub:`` serves on ``hub.url`` from a thread; ``hub.state`` holds the repos."""

    def __init__(self):
        self.state = HubState()
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), make_handler(self.state))
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def __enter__(self) -> HubStandIn:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.shutdown()
        self.server.server_close()
