"""The analysts' dashboard: a Streamlit app (`app.py`) over the queries in `queries.py`."""
