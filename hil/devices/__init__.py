"""Device drivers: motion stage, transducer board and audio interface."""
