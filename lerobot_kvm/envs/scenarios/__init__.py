"""One module per scenario, named by its id; `scenario.SCENARIOS` imports a module when its class is first needed."""
