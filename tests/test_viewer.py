"""The viewer: the latest-frame endpoints, the page in headless Chromium (Debian's `chromium`), and
`scripts/demo.sh` end to end (service + simulation + page address, stopped by Ctrl-C)."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import time
from contextlib import contextmanager
from html.parser import HTMLParser

import httpx
import numpy as np
import pytest
from service_server import FAST_QUALITY, ROOT, ServiceProcess, free_port

from garment_render_client import RenderClient, ServiceError
from simulation import ClothSettings, ClothSim, mannequin, sheet
from simulation.feed import DrapeFeed, upload_studio_environment

TOKEN = "viewer-test-token"
OUTPUT = {"width": 96, "height": 80}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = ServiceProcess(tmp_path_factory.mktemp("viewer"), token=TOKEN)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def scenes(server):
    """Two scenes fed by one simulation, 3 frames: one answered as PNG, one as EXR (its PNG for the
    viewer is made on request)."""
    with RenderClient(server.url, token=TOKEN) as c:
        env = upload_studio_environment(c, 128)
        sim = ClothSim(sheet(16), mannequin(), ClothSettings(frame_dt_s=1 / 10))
        png = DrapeFeed(c, sim, env["id"], quality=dict(FAST_QUALITY), output=OUTPUT, format="png", name="png")
        exr = DrapeFeed(c, sim, env["id"], quality=dict(FAST_QUALITY), output=OUTPUT, format="exr", name="exr")
        empty = c.create_scene(env["id"], name="empty", positions=sim.positions, faces=sim.cloth.faces,
                               quality=dict(FAST_QUALITY), output=OUTPUT)
        answers = []
        for k in range(3):
            if k:
                sim.step_frame()
            answers.append((png.post(k)[0], exr.post(k)[0]))
        yield {"png": png.scene_ids[0], "exr": exr.scene_ids[0], "empty": empty["id"], "answers": answers}


def test_latest_frame_endpoints(server, scenes):
    with RenderClient(server.url, token=TOKEN) as c:
        listing = {s["scene_id"]: s for s in c._json("GET", "/frames/latest")}
        assert {scenes["png"], scenes["exr"], scenes["empty"]} <= set(listing)
        assert listing[scenes["empty"]]["frame"] is None
        for key in ("png", "exr"):
            frame = listing[scenes[key]]["frame"]
            assert frame["frame_index"] == 2 and frame["sequence"] == 3
            assert (frame["width"], frame["height"]) == (96, 80)
            assert frame["timings_ms"]["render"] > 0 and frame["frame_rate_hz"] > 0
            r = c.http.get(frame["image_url"])
            assert r.status_code == 200 and r.headers["content-type"] == "image/png"
            assert r.headers["x-frame-sequence"] == "3"
            import io

            from PIL import Image
            img = np.asarray(Image.open(io.BytesIO(r.content)))
            assert img.shape[:2] == (80, 96) and img.std() > 1
        # The PNG kept for a PNG frame is the very answer the simulator got.
        assert c.http.get(f"/scenes/{scenes['png']}/latest.png").content == scenes["answers"][-1][0].content
        with pytest.raises(ServiceError) as e:
            c._json("GET", f"/scenes/{scenes['empty']}/latest.png")
        assert e.value.status == 404 and "no frame yet" in e.value.detail
    # The page itself needs no token (it holds no data); the data does.
    assert httpx.get(f"{server.url}/view").status_code == 200
    assert httpx.get(f"{server.url}/frames/latest").status_code == 401
    assert httpx.get(f"{server.url}/scenes/{scenes['png']}/latest.png").status_code == 401


def chromium() -> str:
    """The chromium binary; installed through apt (sudo when not root) when missing, as setup.sh does.
    Skips only when it cannot be installed."""
    path = shutil.which("chromium")
    if path:
        return path
    sudo = [] if os.geteuid() == 0 else ["sudo", "-n"]
    if not shutil.which("apt-get") or (sudo and not shutil.which("sudo")):
        pytest.skip("chromium is missing and cannot be installed here (no apt-get, or not root and no sudo)")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    out = subprocess.run(sudo + ["apt-get", "update", "-qq"], capture_output=True, text=True, env=env)
    if out.returncode == 0:
        out = subprocess.run(sudo + ["apt-get", "install", "-y", "-qq", "--no-install-recommends", "chromium"],
                             capture_output=True, text=True, env=env)
    path = shutil.which("chromium")
    if not path:
        pytest.skip(f"chromium is missing and `apt-get install chromium` failed: {out.stderr.strip()[-500:]}")
    return path


class _Dom(HTMLParser):
    """Elements of the dumped DOM: (tag, attributes, text that follows directly)."""

    def __init__(self):
        super().__init__()
        self.elements: list[tuple[str, dict, list[str]]] = []

    def handle_starttag(self, tag, attrs):
        self.elements.append((tag, dict(attrs), []))

    def handle_data(self, data):
        if self.elements and data.strip():
            self.elements[-1][2].append(data.strip())


def test_page_in_headless_chromium_shows_every_scene_with_its_latest_frame(server, scenes, tmp_path):
    browser = chromium()
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=5000", "--dump-dom",
           f"{server.url}/view#token={TOKEN}"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    dom = _Dom()
    dom.feed(out.stdout)
    sections = {a["data-scene-id"]: a for t, a, _ in dom.elements if t == "section" and "data-scene-id" in a}
    assert {scenes["png"], scenes["exr"], scenes["empty"]} <= set(sections), out.stdout[-3000:]
    for key in ("png", "exr"):
        sid = scenes[key]
        assert sections[sid].get("data-shown-sequence") == "3"
        # The section's elements, in order, up to the next section.
        start = next(i for i, (t, a, _) in enumerate(dom.elements) if a.get("data-scene-id") == sid)
        own = []
        for t, a, text in dom.elements[start + 1:]:
            if t == "section":
                break
            own.append((t, a, text))
        img = next(a for t, a, _ in own if t == "img")
        assert img["data-natural-width"] == "96" and img["data-natural-height"] == "80"
        assert img["src"].startswith("blob:")
        meta = " ".join(" ".join(text) for t, a, text in own if a.get("class") == "meta")
        assert re.search(r"frame 2 \(#3 of 3\), 96x80", meta), meta
        stages = {a["data-stage"] for t, a, _ in own if t == "tr"}
        assert {"render", "shading", "total"} <= stages
        cells = [" ".join(text) for t, a, text in own if t == "td" and a.get("class") == "ms"]
        assert cells and all(re.fullmatch(r"\d+\.\d ms", c) for c in cells)
    assert "no frame yet" in out.stdout
    status = next((a, text) for t, a, text in dom.elements if a.get("id") == "status")
    assert status[0].get("class") != "error" and "3 scene(s)" in " ".join(status[1]), status


@pytest.mark.system
def test_demo_script_serves_the_page_and_stops_on_ctrl_c(tmp_path):
    """`bash scripts/demo.sh` as a user runs it: it sets up, starts the service and the simulation,
    prints the page's address; frames arrive; Ctrl-C (SIGINT to its process group, as a terminal
    sends it) stops the service and the simulation."""
    port = free_port()
    proc = subprocess.Popen(["bash", "scripts/demo.sh", "--port", str(port), "--frames", "4", "--size", "64x64",
                             "--spacing", "0.06"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 240
        url = None
        while url is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            m = re.search(r"the viewer is at (http://\S+/view)", line)
            url = m.group(1) if m else None
        assert url == f"http://127.0.0.1:{port}/view", "".join(lines[-30:])
        base = url.rsplit("/view", 1)[0]
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            lines.append(line)
            if "the simulation is done" in line:
                break
        latest = httpx.get(f"{base}/frames/latest", timeout=10).json()
        assert len(latest) == 1 and latest[0]["frame"]["sequence"] == 4, "".join(lines[-30:])
        assert httpx.get(f"{base}{latest[0]['frame']['image_url']}", timeout=10).status_code == 200
        assert "<title>garment-render" in httpx.get(url, timeout=10).text

        os.killpg(proc.pid, signal.SIGINT)
        rest, _ = proc.communicate(timeout=60)
        lines.append(rest)
        assert "demo: stopped" in rest
        with pytest.raises(httpx.TransportError):
            httpx.get(f"{base}/health/live", timeout=2)
        # Nothing of the demo is left running.
        left = subprocess.run(["pgrep", "-s", str(proc.pid)], capture_output=True, text=True).stdout.split()
        assert left == [], "".join(lines[-30:])
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


class _DevTools:
    """Chrome's DevTools protocol over its websocket: commands answered in order, events skipped."""

    def __init__(self, ws):
        self.ws, self.next_id = ws, 0

    def send(self, method: str, **params) -> dict:
        import json

        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=60))
            if msg.get("id") == self.next_id:
                assert "error" not in msg, msg
                return msg["result"]

    def eval(self, expression: str):
        r = self.send("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        assert "exceptionDetails" not in r, r
        return r["result"].get("value")

    def wait_for(self, expression: str, timeout_s: float = 60.0):
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.eval(expression)
            if value:
                return value
            assert time.monotonic() < deadline, f"the page never had {expression}"
            time.sleep(0.2)


@contextmanager
def driven_page(url: str, profile):
    """The page at `url` in headless Chromium, driven through its DevTools protocol (_DevTools)."""
    from websockets.sync.client import connect

    proc = subprocess.Popen([chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                             "--disable-background-networking", "--disable-component-update", "--disable-sync",
                             "--remote-debugging-port=0", f"--user-data-dir={profile}", "--window-size=1200,2400", url],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while not (profile / "DevToolsActivePort").exists():
            assert time.monotonic() < deadline and proc.poll() is None, "chromium did not open its DevTools port"
            time.sleep(0.1)
        port = int((profile / "DevToolsActivePort").read_text().split()[0])
        pages = [t for t in httpx.get(f"http://127.0.0.1:{port}/json/list").json() if t["type"] == "page"]
        with connect(pages[0]["webSocketDebuggerUrl"], max_size=None) as ws:
            yield _DevTools(ws)
    finally:
        proc.terminate()
        proc.wait(30)


def click(page: _DevTools, element_js: str) -> None:
    """A left click of the mouse on the element `element_js` evaluates to, scrolled into view."""
    x, y = page.eval(f"""(() => {{
        const b = {element_js};
        b.scrollIntoView();
        const r = b.getBoundingClientRect();
        return [r.x + r.width / 2, r.y + r.height / 2];
    }})()""")
    for kind in ("mousePressed", "mouseReleased"):
        page.send("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", clickCount=1)


def test_the_page_driven_in_chromium_orbits_turns_the_light_switches_colourway_and_charts_timings(server, scenes,
                                                                                                   tmp_path):
    """A person's use of the page, in headless Chromium driven through its DevTools protocol: on a scene
    with a colourway, the orbit, height and light sliders are moved, the colourway and another preset
    chosen, the render button clicked with the mouse; the scene's current pose is rendered again so (its
    latest frame the view, the sheet's one tile), shown, and its stages drawn as bars."""
    with RenderClient(server.url, token=TOKEN) as c:
        env = c._json("GET", "/environments")[0]["id"]
        sim = ClothSim(sheet(12), mannequin(), ClothSettings(frame_dt_s=1 / 10))
        scene = c.create_scene(env, name="driven", positions=sim.positions, faces=sim.cloth.faces,
                               quality=dict(FAST_QUALITY), output=OUTPUT,
                               colourways=[{"albedo": [0.1, 0.2, 0.8], "specular": 0.3, "glossiness": 0.7}])
        c.send_frame(scene["id"], sim.positions)
        sid = scene["id"]
        with driven_page(f"{server.url}/view#token={TOKEN}", tmp_path / "profile") as page:
            card = f'document.querySelector(\'[data-scene-id="{sid}"]\')'
            page.wait_for(f"{card} && {card}.getAttribute('data-shown-sequence') === '1'")
            assert page.eval(f"{card}.querySelectorAll('select[name=colourway] option').length") == 2
            assert page.eval(f"{card}.querySelector('select[name=preset]').value") == "fast"
            # The sliders moved and the colourway chosen as their input events say, then a mouse click.
            page.eval(f"""(() => {{
                const c = {card};
                for (const [n, v] of [["azimuth", 90], ["elevation", 20], ["rotation", 135]]) {{
                    const i = c.querySelector(`input[name=${{n}}]`);
                    i.value = String(v);
                    i.dispatchEvent(new Event("input"));
                }}
                for (const [n, v] of [["colourway", "1"], ["preset", "balanced"]]) {{
                    const s = c.querySelector(`select[name=${{n}}]`);
                    s.value = v;
                    s.dispatchEvent(new Event("change"));
                }}
            }})()""")
            assert page.eval(f"{card}.querySelector('.controls .value').textContent") == "90\u00b0"
            click(page, f"{card}.querySelector('button.render')")
            page.wait_for(f"{card}.getAttribute('data-rendered') === '90,20,135,1,balanced'")
            # The view is the scene's latest frame, shown by the next poll, its stages as bars.
            page.wait_for(f"{card}.getAttribute('data-shown-sequence') === {card}.getAttribute('data-rendered-sequence')")
            bars = page.eval(f"[...{card}.querySelectorAll('.bar')].map(b => Number(b.dataset.width))")
            assert len(bars) >= 4 and max(bars) == 120 and sum(b > 0 for b in bars) >= 3, bars
            assert page.eval(f"{card}.querySelector('img.frame').getAttribute('data-natural-width')") == "96"
        latest = c._json("GET", f"/scenes/{sid}/latest")
        assert latest["frame"]["sequence"] == 2 and "shading" in latest["frame"]["timings_ms"]
        # Another preset's views are another picture of the same pose (its own PEM set and maps).
        pictures = []
        for preset in ("fast", "accurate"):
            r = c.http.post(f"/scenes/{sid}/frames/views", headers={"Authorization": f"Bearer {TOKEN}"},
                            params={"orbit": "0,0", "layout": "none", "colourway": 0, "preset": preset})
            assert r.status_code == 200, r.text
            pictures.append(r.content)
        assert pictures[0] != pictures[1]
        # What the page sends, refused where it is wrong, by name.
        auth = {"Authorization": f"Bearer {TOKEN}"}
        for params, content, words in (({"orbit": "90", "layout": "none"}, b"", "AZ,EL"),
                                       ({"orbit": "0,0", "layout": "none", "colourway": 2}, b"", "colourway 2"),
                                       ({"orbit": "0,0", "layout": "none"}, b"\0" * 12, "send no body"),
                                       ({"orbit": "0,0", "turntable": 2, "layout": "none"}, b"", "one of the three")):
            r = c.http.post(f"/scenes/{sid}/frames/views", params=params, content=content,
                            headers={**auth, "Content-Type": "application/octet-stream"})
            assert r.status_code == 422 and words in r.json()["detail"], (params, r.text)
        c.delete_scene(sid)


def test_a_fabric_uploaded_after_its_scene_is_chosen_in_the_page_and_rendered(server, scenes, tmp_path):
    """The designer's fabric choice: a .u3ma uploaded while the page is open appears in each scene's
    fabric list; chosen and added with the mouse it becomes the scene's next colourway (named by the
    fabric), chosen at once, and the render button draws the garment in it."""
    from service_server import garment
    from u3m_files import color, document, scalar, u3ma_bytes, visualisation

    blue = u3ma_bytes(document("1.1", visualisation("1.1", basecolor=color((0.05, 0.1, 0.8)), roughness=scalar(0.7)),
                               name="Blue twill"), {})
    with RenderClient(server.url, token=TOKEN) as c:
        env = c._json("GET", "/environments")[0]["id"]
        mesh = garment(16)
        scene = c.create_scene(env, name="fabric", positions=mesh.positions, faces=mesh.faces, uvs=mesh.uvs,
                               material={"model": "pbr", "albedo": [0.8, 0.15, 0.1], "roughness": 0.7},
                               quality=dict(FAST_QUALITY), output={**OUTPUT, "background": "black"})
        sid = scene["id"]
        c.send_frame(sid, mesh.positions)
        with driven_page(f"{server.url}/view#token={TOKEN}", tmp_path / "profile") as page:
            card = f'document.querySelector(\'[data-scene-id="{sid}"]\')'
            page.wait_for(f"{card} && {card}.getAttribute('data-shown-sequence') === '1'")
            fabric = c.upload_fabric(blue, name="blue-twill.u3ma")["id"]
            # Listed by the next poll; chosen, added and rendered with the mouse.
            page.wait_for(f"[...{card}.querySelectorAll('select[name=fabric] option')].some(o => o.value === '{fabric}')")
            page.eval(f"(() => {{ const s = {card}.querySelector('select[name=fabric]'); s.value = '{fabric}'; "
                      "s.dispatchEvent(new Event('change')); })()")
            click(page, f"{card}.querySelector('button.add-fabric')")
            page.wait_for(f"{card}.getAttribute('data-added-colourway') === '1'")
            chosen = page.eval(f"(() => {{ const s = {card}.querySelector('select[name=colourway]'); "
                               "return [s.value, s.options[s.selectedIndex].textContent]; })()")
            assert chosen == ["1", "blue-twill.u3ma"], chosen
            click(page, f"{card}.querySelector('button.render')")
            page.wait_for(f"{card}.getAttribute('data-rendered') === '0,0,0,1,fast'")
            page.wait_for(f"{card}.getAttribute('data-shown-sequence') === {card}.getAttribute('data-rendered-sequence')")
            assert "error" not in (page.eval("document.getElementById('status').className") or "")
        import io

        from PIL import Image
        latest = np.asarray(Image.open(io.BytesIO(c.http.get(f"/scenes/{sid}/latest.png").content)))
        lit = latest[..., 3] == 255
        assert lit.sum() > 200 and latest[lit, 2].mean() - latest[lit, 0].mean() > 10   # blue, not the red garment
        assert c._json("GET", f"/scenes/{sid}")["fabrics"] == [fabric]
        c.delete_scene(sid)
        c.delete_fabric(fabric)
