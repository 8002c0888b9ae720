"""The surgical-training GUI (``surrol-data gui``): pick a task, press play, operate, exit.

Panda3D draws it (:mod:`surrol_data.render`); a haptic session (:mod:`surrol_data.collect.haptic_source`)
records every attempt with provenance. Importing this package imports nothing heavy.
"""
