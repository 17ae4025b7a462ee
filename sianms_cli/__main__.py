from sianms_cli.entry import main

main()
