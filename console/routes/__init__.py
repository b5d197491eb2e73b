"""The console's HTTP routes, one router per concern (pages, runs, simulator, calibration),
put together by ``console.api.create_app``."""
