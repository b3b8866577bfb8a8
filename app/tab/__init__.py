"""One browser tab of the workbench (:class:`app.tab.page.Tab`), split by concern: state, scene, panels, refresher."""
