"""Open the gateway's live view in headless Chromium (Debian's, through chromedriver) while a
run drives, and check the page as a person would see it.

Usage: view.py URL SCREENSHOT.png
       view.py --fleet URL SCREENSHOT.png NAME...   (a fleet's run: each named vehicle drawn
                  with a body and moving, the fleet table, each one's last state)
Starts Chromium first and prints "ready" (the caller starts the run then, so a slow browser
start never misses it), waits for the view to answer, waits for the page to draw the robot, then for the robot marker to move; checks the state,
the obstacles with their planning circles, the streamlines, the room's items as drawn, the latency bars, the axes in
metres and the numbers beside them; saves a screenshot. Then waits for the run to end and
reads the final screen: the state and its reason kept, the numbers, the header's cycle
count against the histogram's. Prints a JSON summary; exits 1 naming what failed.
"""
import json
import sys

import _chromium as chromium

from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait


def await_end(driver, failures):
    """Wait for the page to say the run ended (or the gateway went), at most 60 s."""
    try:
        WebDriverWait(driver, 60, poll_frequency=0.2).until(
            lambda d: d.find_element(By.ID, "link").text.startswith(("run ended", "disconnected")))
    except Exception:
        failures.append("the page never saw the run end")


FLEET_READ = """
    return [...document.querySelectorAll('#vehicles g.vehicle')].map(g => {
      const body = g.querySelector('circle.body');
      const name = g.querySelector('text');
      const row = document.querySelector(`#fleet tr[data-name="${g.dataset.name}"] td`);
      return { name: g.dataset.name, state: g.dataset.state, label: name ? name.textContent : null,
               at: body ? [parseFloat(body.dataset.x), parseFloat(body.dataset.y)] : null,
               path: (g.querySelector('polyline').getAttribute('points') || '').split(' ').filter(p => p).length,
               row: row ? row.textContent : null };
    });"""


def fleet(url, shot, names):
    """A fleet's run: every named vehicle drawn with a body, each moving; the fleet table; each
    vehicle's last state once the run ends."""
    driver = chromium.headless()
    failures, out = [], {}
    print("ready", flush=True)
    try:
        chromium.await_view(url)
        driver.get(url)
        wait = WebDriverWait(driver, 30, poll_frequency=0.1)
        drawn = lambda: {v["name"]: v for v in driver.execute_script(FLEET_READ)}
        try:
            wait.until(lambda d: all((drawn().get(n) or {}).get("at") for n in names))
        except Exception:
            failures.append(f"not every vehicle drawn with a body: {drawn()}")
        first = drawn()
        moved = lambda n: (v := drawn().get(n)) and v["at"] and (first.get(n) or {}).get("at") and \
            abs(v["at"][0] - first[n]["at"][0]) + abs(v["at"][1] - first[n]["at"][1]) > 0.05
        for n in names:
            try:
                wait.until(lambda d: moved(n))
            except Exception:
                failures.append(f"{n} stayed at {first.get(n)}")
        out["running"] = drawn()
        driver.save_screenshot(shot)
        await_end(driver, failures)
        out["final"] = drawn()
    finally:
        driver.quit()
    out["failures"] = failures
    print(json.dumps(out))
    return 1 if failures else 0


if sys.argv[1] == "--fleet":
    sys.exit(fleet(sys.argv[2], sys.argv[3], sys.argv[4:]))

url, shot = sys.argv[1], sys.argv[2]
driver = chromium.headless()
failures = []
out = {}
print("ready", flush=True)
try:
    # The run starts after "ready": poll until its view answers (connection refused until then).
    chromium.await_view(url)
    driver.get(url)
    wait = WebDriverWait(driver, 20, poll_frequency=0.1)
    robot = lambda: driver.find_element(By.ID, "robot")
    wait.until(lambda d: robot().get_attribute("data-x") not in (None, ""))
    first = (float(robot().get_attribute("data-x")), float(robot().get_attribute("data-y")))
    # The robot marker moves as the run drives (positions in metres, from the page's DOM).
    try:
        wait.until(lambda d: abs(float(robot().get_attribute("data-x")) - first[0]) > 0.02)
    except Exception:
        failures.append(f"the robot marker stayed at {first}")
    # The latency histogram follows the metrics, which the view takes once a second.
    counted_js = "return [...document.querySelectorAll('#latency rect.bin')].reduce((s, b) => s + parseInt(b.dataset.count), 0)"
    try:
        wait.until(lambda d: d.execute_script(counted_js) > 0)
    except Exception:
        pass  # reported below as an empty histogram
    # One read of the DOM as drawn (the page redraws ten times a second).
    dom = driver.execute_script("""
        const r = document.getElementById('robot');
        return {
          second: [parseFloat(r.dataset.x), parseFloat(r.dataset.y)],
          state: document.getElementById('state').dataset.state,
          obstacles: document.querySelectorAll('#obstacles g.obstacle').length,
          streamlines: document.querySelectorAll('#streamlines polyline').length,
          counted: [...document.querySelectorAll('#latency rect.bin')].reduce((s, b) => s + parseInt(b.dataset.count), 0),
          path: (document.getElementById('path').getAttribute('points') || '').split(' ').filter(p => p).length,
          room: [...document.querySelectorAll('#walls .room')].map(e =>
            ({ tag: e.tagName, kind: e.classList[1], points: e.getAttribute('points').split(' ').length })),
        };""")
    second, state, counted = tuple(dom["second"]), dom["state"], dom["counted"]
    obstacles, streamlines, path, room = dom["obstacles"], dom["streamlines"], dom["path"], dom["room"]
    if state not in ("running", "stopping", "stopped"):
        failures.append(f"state {state}")
    if obstacles < 1:
        failures.append("no obstacle drawn")
    if streamlines < 5:
        failures.append(f"{streamlines} streamlines")
    if counted <= 0:
        failures.append("an empty latency histogram")
    if path < 2:
        failures.append("no path drawn")
    # The axes: ticks in metres along both edges, and their titles.
    axes = driver.execute_script("""
        const ticks = c => [...document.querySelectorAll('#axes text.tick.' + c)].map(t => parseFloat(t.textContent));
        return { x: ticks('x'), y: ticks('y'),
                 titles: [...document.querySelectorAll('#axes text.title')].map(t => t.textContent) };""")
    if len(axes["x"]) < 3 or len(axes["y"]) < 2 or sorted(axes["titles"]) != ["x (m)", "y (m)"]:
        failures.append(f"axes {axes}")
    # The numbers beside the drawing agree with the drawing (the pose in metres).
    live = driver.execute_script("""
        const v = id => document.getElementById(id).textContent;
        const r = document.getElementById('robot');
        return { x: v('n-x'), marker_x: r.dataset.x, goal: v('n-goal'), speed: v('n-speed'),
                 clearance: v('n-clearance'), obstacle_speeds: v('n-obstacle-speeds') };""")
    if live["x"] == "-" or abs(float(live["x"]) - float(live["marker_x"])) > 0.0006:
        failures.append(f"the position {live['x']} against the marker's {live['marker_x']}")
    for key in ("goal", "speed", "clearance", "obstacle_speeds"):
        if live[key] == "-":
            failures.append(f"no {key} shown while running")
    driver.save_screenshot(shot)
    # The run ends: the page keeps its last state, says so, and its counts agree.
    await_end(driver, failures)
    final = driver.execute_script("""
        const v = id => document.getElementById(id).textContent;
        const caption = document.getElementById('latency-caption');
        return { state: document.getElementById('state').dataset.state, reason: v('reason'), link: v('link'),
                 cycles: parseInt(v('cycles')), histogram_cycles: caption ? parseInt(caption.dataset.cycles) : null,
                 goal: parseFloat(v('n-goal')), x: parseFloat(v('n-x')) };""")
    if final["state"] != "stopped" or final["reason"] != "goal reached":
        failures.append(f"final state {final['state']} ({final['reason']})")
    if final["cycles"] != final["histogram_cycles"]:
        failures.append(f"header {final['cycles']} cycles, histogram {final['histogram_cycles']}")
    out = {"first": first, "second": second, "state": state, "obstacles": obstacles,
           "streamlines": streamlines, "room": room, "latency_cycles": counted, "path_points": path,
           "axes": axes, "live": live, "final": final}
finally:
    driver.quit()
out["failures"] = failures
print(json.dumps(out))
sys.exit(1 if failures else 0)
