"""One browser tab of the workbench (:class:`app.tab.tab.Tab`), split by concern: state, scene, panels, refresher."""
