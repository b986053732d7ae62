"""Keep the gateway's live view open in headless Chromium while runs come and go.

Usage: demo_load.py URL
Starts Chromium and prints "ready"; then, for every line on stdin ("run"), waits for the view
at URL to answer, loads the page (which renders every frame the server sends until the run
ends) and prints "drawn N" once the page has drawn the robot. Ends at the end of stdin.
"""
import sys

import _chromium as chromium

from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

url = sys.argv[1]
driver = chromium.headless()
print("ready", flush=True)
try:
    for n, _ in enumerate(sys.stdin, 1):
        chromium.await_view(url)
        driver.get(url)
        robot = lambda: driver.find_element(By.ID, "robot")
        WebDriverWait(driver, 30, poll_frequency=0.1).until(lambda d: robot().get_attribute("data-x") not in (None, ""))
        print(f"drawn {n}", flush=True)
finally:
    driver.quit()
