"""``cellsight view``: an interactive 3D view of a cell in a web browser, built with viser.

The cell's objects as meshes at given joints (or HOME), each camera as a frustum showing its
MuJoCo image with the features and windows drawn on it, the workpieces' feature points coloured
by what a chosen camera sees; with a run's folder, a timeline that replays it (logged joints,
the true and the estimated part, the logged visibility, selection and measurements).

Modules: :mod:`~cellsight.view.states` (what is shown at one instant), :mod:`~.replay` (a run
folder read back), :mod:`~.scene` (the viser scene), :mod:`~.images` (the cameras' images),
:mod:`~.timeline`, :mod:`~.app` (the server), :mod:`~.command` (the command line,
``register(sub)``), :mod:`~.inputs` (its values).
"""
