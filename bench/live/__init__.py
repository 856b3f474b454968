"""The live view: a page on 127.0.0.1 that shows a trial (or a comparison) while it runs."""
