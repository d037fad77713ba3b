"""The admin dashboard: its routes and sessions server side, and its pages in a real headless
Chromium."""
