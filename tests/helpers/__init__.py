"""What the tests share (tests/ is on sys.path under pytest; import as `helpers.captures`, ...).

    captures.py              capture folders written in each phone app's / dataset's own layout
    scene.py                 the small scene those captures show, with exact poses
    nerfcapture_publisher.py a NeRFCapture app stand-in publishing frames over DDS (loopback)
    viewer.py                a scripted SlamRun (FakePipeline), test maps, polling helpers
    engine.py                small synthetic sources and maps for the engine's unit tests
    configs.py               settings files the run tests share (TINY)
"""
