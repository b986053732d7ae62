"""Keep the gateway's live view open in headless Chromium while runs come and go.

Usage: view_load.py URL
Starts Chromium and prints "ready"; then, for every line on stdin ("run"), waits for the view
at URL to answer, loads the page (which renders every frame the server sends until the run
ends) and prints "drawn N" once the page has drawn the robot. Ends at the end of stdin.
"""
import sys
import tempfile
import time
import urllib.request

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

url = sys.argv[1]
options = webdriver.ChromeOptions()
options.binary_location = "/usr/bin/chromium"
for flag in ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--window-size=1420,700", f"--user-data-dir={tempfile.mkdtemp()}"]:
    options.add_argument(flag)
driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
print("ready", flush=True)
try:
    for n, _ in enumerate(sys.stdin, 1):
        deadline = time.monotonic() + 60
        while True:
            try:
                urllib.request.urlopen(url + "frame.json", timeout=2).read()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        driver.get(url)
        robot = lambda: driver.find_element(By.ID, "robot")
        WebDriverWait(driver, 30, poll_frequency=0.1).until(lambda d: robot().get_attribute("data-x") not in (None, ""))
        print(f"drawn {n}", flush=True)
finally:
    driver.quit()
