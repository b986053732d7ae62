"""Open the gateway's live view in headless Chromium (Debian's, through chromedriver) while a
run drives, and check the page as a person would see it.

Usage: view_browser.py URL SCREENSHOT.png
Starts Chromium first and prints "ready" (the caller starts the run then, so a slow browser
start never misses it), waits for the view to answer, waits for the page to draw the robot, then for the robot marker to move; checks the state,
the obstacles with their planning circles, the streamlines and the latency bars; saves a
screenshot. Prints a JSON summary; exits 1 naming what failed.
"""
import json
import sys

import chromium

from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

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
        };""")
    second, state, counted = tuple(dom["second"]), dom["state"], dom["counted"]
    obstacles, streamlines, path = dom["obstacles"], dom["streamlines"], dom["path"]
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
    driver.save_screenshot(shot)
    out = {"first": first, "second": second, "state": state, "obstacles": obstacles,
           "streamlines": streamlines, "latency_cycles": counted, "path_points": path}
finally:
    driver.quit()
out["failures"] = failures
print(json.dumps(out))
sys.exit(1 if failures else 0)
